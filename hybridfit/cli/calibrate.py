"""``hybridfit calibrate``: fit the hand model's geometry to a dataset's annotated frames."""

from __future__ import annotations

from pathlib import Path

import sys

import numpy as np

from ..fitting.calibrate import calibrate, to_toml
from ..datasets.skeletons import dataset_model_config, skeleton
from ..errors import HybridfitError
from ..io import atomic_path, frame_slice
from ._common import (MODEL_KEY, check_plugin, declare_paths, fraction, load_model_toml, non_negative_int, positive_int,
                      read_results, seed_int)

#: the model ``hybridfit calibrate`` calibrates unless told otherwise: on the tuning data (ICVL frames
#: 0-99, every 20th NYU actor-2 frame) it refines strong predictors at a lower cost than hand26
CALIBRATED_MODEL = "hand27"


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="estimate the hand model's bone lengths and geometry from annotated frames")
    p.add_argument("--dataset", required=True, help="skeleton of the ground truth: icvl, nyu, nyu36, "
                   "msra, mediapipe, mano or a skeleton .toml file")
    p.add_argument("--ground-truth", required=True, metavar="LABELS", help="ground truth in the common results format")
    p.add_argument("--frames", metavar="START:STOP", help="frames to use (default: all): up to 80 of them spanning "
                   "the pose range calibrate, --holdout of them, spread over them, are held out")
    p.add_argument("--holdout", type=fraction, default=0.2, metavar="FRACTION",
                   help="share of the frames, spread over them, held out to measure the fit error of the calibrated "
                        "model on frames it was not calibrated on (default 0.2; 0: none)")
    p.add_argument("--out", required=True, metavar="MODEL.toml", help="model config to write")
    p.add_argument("--model", help="hand model plugin (default: the one --model-config names, else hand27, which "
                   "follows real annotations closer than hand26: docs/results.md, Real hands); the model config "
                   "written names it, so `hybridfit fit --model-config` fits with it")
    p.add_argument("--model-config", metavar="TOML", help="the model's other settings (geometry starts at its prior)")
    p.add_argument("--hand", choices=("auto", "right", "left"), default="auto", help="handedness (default: the better fit)")
    p.add_argument("--rounds", type=non_negative_int, default=2, help="pose-fit / geometry alternations (default 2)")
    p.add_argument("--budget", type=positive_int, default=3400, help="evaluations per frame of each pose fit")
    p.add_argument("--seed", type=seed_int, default=0)
    p.add_argument("--jobs", type=positive_int, default=1)
    declare_paths(p, inputs=("--ground-truth", "--model-config"), outputs=("--out",))
    p.set_defaults(func=run)


def run(args) -> int:
    sk = skeleton(args.dataset)
    truth = read_results(args.ground_truth, args.dataset)
    frames = np.arange(len(truth))[frame_slice(args.frames, len(truth))]
    truth = truth[frames]
    args.model, config = load_model_toml(args.model_config, args.model)
    args.model = args.model or CALIBRATED_MODEL
    check_plugin("model", args.model, config, args.model_config)  # a typo names the file and the closest key
    start = dataset_model_config(args.model, config, args.dataset)
    mirror = {"auto": None, "right": False, "left": True}[args.hand]
    result = calibrate(truth, sk.model_names, model=args.model, model_config=start, mirror=mirror,
                       holdout=args.holdout, rounds=args.rounds, budget=args.budget, seed=args.seed, jobs=args.jobs,
                       progress=sys.stderr.isatty(), log=lambda m: print(f"  {m}"))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cal, held = frames[result.calibration_frames], frames[result.heldout_frames]
    where = (f"{len(cal)} frames spanning the pose range of frames {frames[0]}-{frames[-1]}"
             + (f", {len(held)} held out spread over them" if len(held) else ""))
    heldout = f"{result.error_heldout:.2f} mm held out ({len(held)} frames)" if len(held) else "no frames held out"
    header = (f"# {args.model} calibrated by `hybridfit calibrate --dataset {sk.dataset}` on {where} of "
              f"{args.ground_truth}\n"
              f"# fit error {result.error_before:.2f} mm before, {result.error_after:.2f} mm after (in-sample), "
              f"{heldout}\n")
    with atomic_path(out) as tmp:  # an existing model file is replaced only by a complete one
        tmp.write_text(header + to_toml({MODEL_KEY: args.model, **result.settings}))
    hand = _hand(result.settings, args.model)
    print(f"calibrated on {len(cal)} frames{hand}: mean fit error {result.error_before:.2f} mm before, "
          f"{result.error_after:.2f} mm after (in-sample); {heldout} -> {out}")
    if len(held):
        print(f"floor {result.error_heldout:.2f} mm (the held-out annotations fitted); a "
              f"{result.predictor_heldout:.2f} mm predictor fitted: {result.refined_heldout:.2f} mm "
              f"({result.refined_heldout - result.predictor_heldout:+.2f} mm)")
    print("per point after (mm): " + ", ".join(
        f"{n} {e:.1f}" for n, e in zip(sk.names, np.asarray(result.per_point_after))))
    if len(held):
        print("per point held out (mm): " + ", ".join(
            f"{n} {e:.1f}" for n, e in zip(sk.names, np.asarray(result.per_point_heldout))))
    return 0


def _hand(settings: dict, model: str) -> str:
    """' (left hand)' / ' (right hand)' for a model with a mirror setting, else ''."""
    from .. import registry

    key = registry.get("model", model).mirror_setting
    return "" if key is None else f" ({'left' if settings[key] else 'right'} hand)"
