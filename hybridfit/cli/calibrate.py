"""``hybridfit calibrate``: fit the hand model's geometry to a dataset's annotated frames, or
(``--proposals``) to a sequence's own proposals when it has no annotations (self-calibration)."""

from __future__ import annotations

from pathlib import Path

import sys

import numpy as np

from ..fitting.calibrate import calibrate, self_calibrate, to_toml
from ..datasets.points import check_millimetres
from ..datasets.skeletons import dataset_model_config, fit_settings, skeleton
from ..errors import HybridfitError
from ..io import atomic_path, frame_slice, load_proposals
from ._common import (FRAMES_HELP, MODEL_KEY, check_plugin, declare_paths, fraction, frames_range, load_model_toml,
                      non_negative_int, positive_int, read_results, seed_int, budget_int)

#: the model ``hybridfit calibrate`` (and ``fit``'s self-calibration) calibrates unless told
#: otherwise: hand29, whose palm arches at the ring and little CMCs as real palms do. On the tuning
#: data (ICVL frames 0-99: `benchmarks/bench_strong.py --data icvl --calibrate 0:80 --test 80:100`)
#: a 5 mm predictor refined cost +0.53 mm calibrated and +0.16 self-calibrated, hand27 +1.00 and
#: +0.80 (floor 3.68 against 4.11 mm); on synthetic stress subjects, whose palms are rigid by
#: construction, it is 0.04-0.11 mm behind hand27 (docs/results.md, One rigid hand)
CALIBRATED_MODEL = "hand29"
#: share of the frames held out by default (with --ground-truth)
HOLDOUT = 0.2


def register(sub) -> None:
    p = sub.add_parser("calibrate", help="estimate the hand model's bone lengths and geometry from annotated frames, "
                       "or from a sequence's own proposals (--proposals)")
    p.add_argument("--dataset", help="skeleton of the ground truth (or of the proposals, when their npz names none): "
                   "icvl, nyu, nyu36, msra, mediapipe, mano or a skeleton .toml file")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--ground-truth", metavar="LABELS", help="ground truth in the common results format")
    src.add_argument("--proposals", metavar="FILE.npz", help="self-calibration: a proposals file of one subject "
                     "without ground truth (as `hybridfit fit` reads it); the skeleton comes from its most confident "
                     "proposals over up to 100 frames spanning its pose range")
    p.add_argument("--frames", type=frames_range, metavar="START:STOP", help=f"frames to use: {FRAMES_HELP} "
                   "(default: all): up to 80 of them spanning "
                   "the pose range calibrate, --holdout of them, spread over them, are held out (--proposals: up to "
                   "100 of them with confident proposals, none held out)")
    p.add_argument("--holdout", type=fraction, metavar="FRACTION",
                   help="share of the frames, spread over them, held out to measure the fit error of the calibrated "
                        "model on frames it was not calibrated on (default 0.2; 0: none; --ground-truth only)")
    p.add_argument("--out", required=True, metavar="MODEL.toml", help="model config to write")
    p.add_argument("--model", help="hand model plugin (default: the one --model-config names, else hand29, which "
                   "follows real annotations closer than hand27: docs/results.md, One rigid hand); the model config "
                   "written names it, so `hybridfit fit --model-config` fits with it")
    p.add_argument("--model-config", metavar="TOML", help="the model's other settings (geometry starts at its prior)")
    p.add_argument("--hand", choices=("auto", "right", "left"), default="auto", help="handedness (default: the better fit)")
    p.add_argument("--rounds", type=non_negative_int, help="pose-fit / geometry alternations (default 2; "
                   "--proposals: 3)")
    p.add_argument("--budget", type=budget_int, default=3400, help="evaluations per frame of each pose fit")
    p.add_argument("--seed", type=seed_int, default=0, help="random seed of the pose fits (and of the held-out "
                   "check's simulated predictor), >= 0 (default 0)")
    p.add_argument("--jobs", type=positive_int, default=1, help="parallel fitting processes for the pose fits "
                   "(default 1; results do not depend on it)")
    declare_paths(p, inputs=("--ground-truth", "--proposals", "--model-config"), outputs=("--out",))
    p.set_defaults(func=run)


def run(args) -> int:
    if args.proposals is not None:
        return run_self(args)
    if args.dataset is None:
        raise HybridfitError("--ground-truth needs --dataset (the skeleton of the ground truth)")
    sk = skeleton(args.dataset)
    truth = read_results(args.ground_truth, args.dataset)
    frames = np.arange(len(truth))[frame_slice(args.frames, len(truth))]
    truth = truth[frames]
    args.model, config = load_model_toml(args.model_config, args.model)
    args.model = args.model or CALIBRATED_MODEL
    check_plugin("model", args.model, config, args.model_config)  # a typo names the file and the closest key
    start = dataset_model_config(args.model, config, args.dataset)
    mirror = {"auto": None, "right": False, "left": True}[args.hand]
    rounds = {} if args.rounds is None else {"rounds": args.rounds}
    result = calibrate(truth, sk.model_names, model=args.model, model_config=start, mirror=mirror,
                       holdout=HOLDOUT if args.holdout is None else args.holdout, budget=args.budget, seed=args.seed,
                       jobs=args.jobs, progress=sys.stderr.isatty(), log=lambda m: print(f"  {m}"), **rounds)
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


def run_self(args) -> int:
    """``--proposals``: self-calibration (no ground truth)."""
    if args.holdout is not None:
        raise HybridfitError("--holdout: with --proposals nothing is held out (there is no ground truth to measure "
                             "it against)")
    data = load_proposals(args.proposals)
    check_millimetres(data["proposals"], data["confidences"], args.proposals)
    dataset = args.dataset or (str(data["dataset"]) if "dataset" in data else None)
    frames = np.arange(len(data["proposals"]))[frame_slice(args.frames, len(data["proposals"]))]
    args.model, config = load_model_toml(args.model_config, args.model)
    args.model = args.model or CALIBRATED_MODEL
    check_plugin("model", args.model, config, args.model_config)
    names, start = fit_settings(data.get("joint_names"), data["proposals"].shape[1], dataset, args.model, config,
                                args.proposals)
    names = names or list(_model_joints(args.model, start))
    mirror = {"auto": None, "right": False, "left": True}[args.hand]
    options = {"objective": str(data["objective"])} if "objective" in data else {}  # the objective `fit` uses
    rounds = {} if args.rounds is None else {"rounds": args.rounds}
    result = self_calibrate(data["proposals"][frames], data["confidences"][frames], names, model=args.model,
                            model_config=start, mirror=mirror, budget=args.budget, seed=args.seed, jobs=args.jobs,
                            fit_options=options, progress=sys.stderr.isatty(), log=lambda m: print(f"  {m}"), **rounds)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    cal = frames[result.frames]
    where = (f"{len(cal)} frames spanning the poses of frames {frames[0]}-{frames[-1]} (of {result.eligible} with "
             f"proposals for most points, those the hand follows best)")
    residual = (f"fit {result.residual_before:.2f} mm from the top proposals before, {result.residual_after:.2f} mm "
                f"after (median)")
    header = (f"# {args.model} self-calibrated by `hybridfit calibrate --proposals` on {where} of {args.proposals} "
              f"(no ground truth)\n# {residual}\n")
    with atomic_path(out) as tmp:
        tmp.write_text(header + to_toml({MODEL_KEY: args.model, **result.settings}))
    print(f"self-calibrated on {len(cal)} frames{_hand(result.settings, args.model)}: {residual}; "
          f"proposals' noise about {result.noise_mm:.1f} mm per coordinate -> {out}")
    point_names = skeleton(dataset).names if dataset else names
    print("per point after, median from the top proposals (mm): " + ", ".join(
        f"{n} {e:.1f}" for n, e in zip(point_names, np.asarray(result.per_point_after))))
    if "ground_truth" in data:  # a check only: self-calibration never reads it
        truth = data["ground_truth"][cal]
        before, after = (float(np.nanmean(np.linalg.norm(p - truth, axis=-1)))
                         for p in (result.points_before, result.points_after))
        print(f"against the file's ground_truth (not used to calibrate): mean fit error {before:.2f} mm before, "
              f"{after:.2f} mm after on the calibration frames")
    return 0


def _model_joints(model: str, config: dict) -> tuple[str, ...]:
    from .. import registry

    return registry.create("model", model, config).joint_names


def _hand(settings: dict, model: str) -> str:
    """' (left hand)' / ' (right hand)' for a model with a mirror setting, else ''."""
    from .. import registry

    key = registry.get("model", model).mirror_setting
    return "" if key is None else f" ({'left' if settings[key] else 'right'} hand)"
