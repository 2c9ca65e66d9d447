"""``hybridfit calibrate``: fit the hand model's geometry to a dataset's annotated frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..calibrate import calibrate, to_toml
from ..datasets.results import read_xyz
from ..datasets.skeletons import skeleton, with_derived_points
from ..errors import HybridfitError
from ._common import load_toml, positive_int


def frame_slice(text: str | None, n: int) -> slice:
    """'START:STOP' (either may be empty) -> a slice within n frames; errors name the option."""
    if not text:
        return slice(0, n)
    try:
        start, stop = (int(t) if t else None for t in text.split(":"))
    except ValueError:
        raise HybridfitError(f"--frames: expected START:STOP, got {text!r}") from None
    s = slice(start, stop)
    if len(range(n)[s]) == 0:
        raise HybridfitError(f"--frames {text}: no frames selected out of {n}")
    return s


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="estimate the hand model's bone lengths and geometry from annotated frames")
    p.add_argument("--dataset", required=True, help="skeleton of the ground truth: icvl, nyu, nyu36, "
                   "msra, mediapipe, mano or a skeleton .toml file")
    p.add_argument("--ground-truth", required=True, metavar="LABELS", help="ground truth in the common results format")
    p.add_argument("--frames", metavar="START:STOP", help="frames to calibrate on (default: all)")
    p.add_argument("--out", required=True, metavar="MODEL.toml", help="hand26 model config to write")
    p.add_argument("--model-config", metavar="TOML", help="starting hand26 settings (default: the built-in hand)")
    p.add_argument("--hand", choices=("auto", "right", "left"), default="auto", help="handedness (default: the better fit)")
    p.add_argument("--rounds", type=int, default=3, help="pose-fit / geometry alternations (default 3)")
    p.add_argument("--budget", type=positive_int, default=3400, help="evaluations per frame of each pose fit")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--jobs", type=positive_int, default=1)
    p.set_defaults(func=run)


def run(args) -> int:
    sk = skeleton(args.dataset)
    truth = read_xyz(args.ground_truth, sk.dataset)
    truth = truth[frame_slice(args.frames, len(truth))]
    start = with_derived_points(load_toml(args.model_config), sk.dataset)
    mirror = {"auto": None, "right": False, "left": True}[args.hand]
    result = calibrate(truth, sk.model_names, model_config=start, mirror=mirror, rounds=args.rounds,
                       budget=args.budget, seed=args.seed, jobs=args.jobs, log=lambda m: print(f"  {m}"))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    header = (f"# hand26 calibrated by `hybridfit calibrate --dataset {sk.dataset}` on {len(truth)} frames of "
              f"{args.ground_truth}\n# fit error {result.error_before:.2f} mm before, {result.error_after:.2f} mm after\n")
    out.write_text(header + to_toml(result.settings))
    hand = "left" if result.settings["mirror"] else "right"
    print(f"calibrated on {len(truth)} frames ({hand} hand): mean fit error {result.error_before:.2f} mm before, "
          f"{result.error_after:.2f} mm after -> {out}")
    print("per point after (mm): " + ", ".join(
        f"{n} {e:.1f}" for n, e in zip(sk.names, np.asarray(result.per_point_after))))
    return 0
