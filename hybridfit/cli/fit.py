"""``hybridfit fit``: fit the hand model to a proposals file."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

from .. import fit as fit_frames
from .. import registry
from ..datasets.points import check_millimetres
from ..datasets.skeletons import fit_settings, skeleton
from ..errors import EXIT_INCOMPLETE, EXIT_INTERRUPTED, EXIT_OK, HybridfitError, PluginError
from ..io import load_proposals, save_npz
from ..datasets.folder import load_dataset
from ..datasets.results import is_keypoints, read_keypoints
from ..metrics import summary
from ..objective import dataset_observations
from ..fitting.calibrate import CONFIDENT_POINTS, self_calibrate, top_proposals
from ..fitting.setup_check import check_setup
from ..fitting.tracking import track
from ..keys import frame_indices
from ._common import add_fit_options, add_keypoint_options, add_plugin_options, check_plugin, declare_paths, plugin_kwargs
from .calibrate import CALIBRATED_MODEL

#: ``--calibrate auto`` self-calibrates only with at least this many frames with proposals for most points
#: (``fitting.calibrate.CONFIDENT_POINTS`` of them; fewer: the model as configured, with a warning when it
#: fits the proposals badly)
AUTO_MIN_FRAMES = 30


#: what ``hybridfit fit --help`` says of the schedule
SCHEDULE_HELP = (
    "Fit the hand model to each frame's joint proposals. The fit is its schedule, every stage's evaluations counted "
    "in --budget: by default (optimizer stepwise-pso, objective clamped-then-soft-l1) PSO on the palm's 7 "
    "parameters (30% of the search budget), then on each finger's 4 (the rest, equally), minimising the paper's "
    "clamped-confidence objective; then a local Levenberg-Marquardt stage of all parameters (local_share 20% of "
    "the budget) on soft-L1 fusion of the proposals. --objective NAME makes every stage minimise NAME; "
    "--optimizer-config 'local_share = 0' is the paper's schedule. The schedule that ran is printed and "
    "stored in the fits file (key schedule, JSON).")


def schedule_line(schedule: str) -> str:
    """One line naming the stages of the schedule most frames ran (a fits file's ``schedule``)."""
    import json

    runs = json.loads(schedule)
    if not runs:
        return "schedule: none (no frame fitted)"
    top = max(runs, key=lambda r: r["frames"])
    stages = ", ".join(f"{s['name']} {s['optimizer']['name']}"
                       + (f" on {s['objective']['name']}" if s["objective"]["name"] != top["stages"][0]["objective"]["name"]
                          else "") + f" {s['budget']}" for s in top["stages"])
    more = f"; {len(runs) - 1} other schedules for frames with points missing" if len(runs) > 1 else ""
    return f"schedule: {stages} (objective {top['stages'][0]['objective']['name']}{more})"


def register(sub) -> None:
    p = sub.add_parser("fit", help="fit the hand model to joint proposals (.npz)", description=SCHEDULE_HELP)
    p.add_argument("proposals", help="npz with proposals (F,J,K,3) mm, confidences (F,J,K), optional joint_names, "
                   "ground_truth, frames (the frames' indices in their data set, which key their random numbers, as "
                   "propose writes them)")
    p.add_argument("--out", required=True, help="output npz: params, joints, objective (the loss), evaluations, "
                   "joint_names, failed, inliers (points within inlier_distance_mm of a proposal), schedule (the "
                   "stages that ran, JSON), ground_truth and frames (copied from the input)")
    add_plugin_options(p)
    add_fit_options(p)
    add_keypoint_options(p)
    p.add_argument("--depth", metavar="DIR", help="a data-set folder (hybridfit synth test) holding the proposals' "
                   "frames (those the file's frames names, else its first frames): their depth, for objectives that "
                   "compare with the depth image (rendered-depth, hybrid)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="fit the frames on the dask.distributed scheduler at "
                   "ADDRESS (tcp://HOST:PORT; `dask scheduler` and `dask worker` start one): the same fits bit for "
                   "bit, a lost worker's chunk run again on another (--jobs is ignored)")
    p.add_argument("--track", action="store_true", help="track the frames as a sequence: each starts from the "
                   "previous fit (one process; --jobs is ignored)")
    p.add_argument("--on-lost", choices=["reinit", "continue"], default="reinit",
                   help="with --track, when a fit is lost: start the next frame from its proposals (default) or "
                   "keep tracking from it")
    p.add_argument("--first-frame", choices=["proposals", "ground-truth"], default="proposals",
                   help="with --track, frame 0's initial guess: its proposals, or the --depth folder's model "
                   "parameters")
    p.add_argument("--hand", choices=("auto", "right", "left"), default="auto",
                   help="the hand of the data: right or left (the model's mirror image), or auto (default): the "
                   "model as configured, or its mirror image where that fits a check on a few frames clearly "
                   "better (said on stderr)")
    p.add_argument("--calibrate", choices=("auto", "self", "none"), default="auto",
                   help="the subject's skeleton: auto (default): self-calibrated from the proposals themselves (as "
                   "`hybridfit calibrate --proposals` does, no ground truth) when they come from a real data set "
                   "(the npz names a dataset, or --dataset is given), no --model-config is given and at least "
                   f"{AUTO_MIN_FRAMES} frames have proposals for {CONFIDENT_POINTS * 100:.0f}%% of their points; self: "
                   "always; none: the model as configured. "
                   f"Self-calibration fits {CALIBRATED_MODEL} unless --model names another")
    p.add_argument("--dataset", help="the proposals' skeleton when the npz has no joint_names (and its derived "
                   "points for its model): icvl, nyu, nyu36, msra, mediapipe, mano or a skeleton .toml file "
                   "(default: the npz's dataset, which propose writes for real data)")
    declare_paths(p, inputs=("proposals", "--depth", "--model-config", "--objective-config", "--optimizer-config"),
                  outputs=("--out",))
    p.set_defaults(func=run)


def load_input(args) -> dict:
    """The proposals to fit: an npz, or MediaPipe/OpenPose keypoints (--hand picks the hand in them)."""
    if is_keypoints(args.proposals):
        return read_keypoints(args.proposals, hand=None if args.hand == "auto" else args.hand,
                              mirrored=args.mirrored, labels=args.labels, unit=args.unit)
    for option, given in (("--mirrored", args.mirrored), ("--unit", args.unit is not None),
                          ("--labels", args.labels != "subject")):
        if given:
            raise HybridfitError(f"{option} applies to MediaPipe and OpenPose keypoints, not to {args.proposals}")
    return load_proposals(args.proposals)


def frame_reasons(data) -> dict[int, str]:
    """Why the input's frames without a hand have none (keypoints: "no hand detected", ...)."""
    if "frame_errors" not in data:
        return {}
    errors = np.asarray(data["frame_errors"])
    return {int(f): str(errors[f]) for f in np.flatnonzero(errors != "")}


def run(args) -> int:
    if args.scheduler and args.track:
        raise HybridfitError("--scheduler fits frames apart; --track fits one sequence in order, in one process")
    data = load_input(args)
    check_millimetres(data["proposals"], data["confidences"], args.proposals)
    given = data.get("frames")  # indices key the frames' random streams; names (the paper's ICVL file) do not
    named = given is not None and np.asarray(given).dtype.kind in "US"
    indices = frame_indices(None if named else given, len(data["proposals"]), f"{args.proposals}: 'frames'")
    if args.objective is None and "objective" in data:  # the objective the file names (other methods' estimates)
        args.objective = str(data["objective"])
    plugins = plugin_kwargs(args)
    extra = {}
    dataset = args.dataset or (str(data["dataset"]) if "dataset" in data else None)  # propose writes it
    args.self_calibrating = wants_calibration(args, data, dataset)
    if args.self_calibrating and args.model is None and args.model_config is None:
        plugins["model"] = CALIBRATED_MODEL  # what `hybridfit calibrate` calibrates
        check_plugin("model", plugins["model"], plugins["model_config"], None)
    key = registry.get("model", plugins["model"]).mirror_setting
    if "hand" in data and args.hand == "auto" and key is not None and key not in plugins["model_config"]:
        plugins["model_config"] = {**plugins["model_config"], key: str(data["hand"]) == "left"}  # the file's hand, checked below
    names, plugins["model_config"] = fit_settings(data.get("joint_names"), data["proposals"].shape[1], dataset,
                                                  plugins["model"], plugins["model_config"], args.proposals)
    if dataset:
        extra["dataset"] = np.asarray(skeleton(dataset).dataset)
    if "ground_truth" in data:
        extra["ground_truth"] = data["ground_truth"]
    if "frames" in data:  # the data set's frame indices, as the file records them (export-angles numbers rows by them)
        extra["frames"] = indices
    depth = depth_frames(args, indices, "frames" in data)
    if not args.depth:  # the hand and the geometry, on a few frames (hybridfit.fitting.setup_check)
        plugins["model_config"] = check_hand_and_geometry(args, data, names, plugins, dataset)
    if args.self_calibrating:
        try:
            plugins["model_config"] = calibrate_skeleton(args, data, names, plugins, dataset)
        except KeyboardInterrupt:  # a stop signal during the self-calibration: nothing fitted, nothing written
            print("interrupted during the self-calibration: nothing fitted", file=sys.stderr)
            return EXIT_INTERRUPTED
    common = dict(joint_names=names, budget=args.budget, seed=args.seed, search_radius_mm=args.search_radius,
                  progress=sys.stderr.isatty(), observations=depth.get("observations"), frames=indices, **plugins)
    if args.track:
        result = track(data["proposals"], data["confidences"], first_params=depth.get("first_params"),
                       settings={"on_lost": args.on_lost}, **common)
        extra["lost"] = result.lost
        result.errors.update({f: m for f, m in frame_reasons(data).items() if result.failed[f]})
    else:
        try:
            result = fit_frames(data["proposals"], data["confidences"], jobs=args.jobs, scheduler=args.scheduler,
                                **common)
            result.errors.update({f: m for f, m in frame_reasons(data).items() if result.failed[f]})
        except PluginError as err:  # a bug, not the user's: keep the finished frames, then let it propagate
            if err.result is not None and (~err.result.failed).any():
                save_npz(args.out, **err.result.to_npz(), **extra)
                print(f"{int((~err.result.failed).sum())} frames fitted before the plugin error saved to {args.out}",
                      file=sys.stderr)
            raise
    save_npz(args.out, **result.to_npz(), **extra)
    F, done = len(result.failed), ~result.failed
    print(f"fitted {int(done.sum())}/{F} frames -> {args.out}")
    print(schedule_line(result.schedule))
    report_failures(result.errors)
    if "ground_truth" in data and done.any():  # finished frames only (after Ctrl-C too)
        s = summary(result.joints[done], data["ground_truth"][done])
        print("mean joint error {mean_error_mm:.2f} mm; success rate @20/40/80 mm: "
              "{success@20mm:.3f} / {success@40mm:.3f} / {success@80mm:.3f}".format(**s)
              + f" ({int(done.sum())} fitted frames)")
    if result.interrupted:
        print(f"interrupted: finished frames saved to {args.out}", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_OK if done.all() else EXIT_INCOMPLETE


def check_hand_and_geometry(args, data: dict, names, plugins: dict, dataset: str | None) -> dict:
    """The model settings to fit with: ``--hand`` applied, or (auto) the mirror image where the
    check finds the data is of the other hand; one warning line for each finding (the other
    hand; with a dataset and no --model-config, a fit far from the proposals: calibrate).
    When the skeleton is then self-calibrated (``args.self_calibrating``), that calibration
    chooses the hand (--hand auto) on many more frames and the geometry is its business: the
    check only looks for points no hand explains (wrong names or units)."""
    key = registry.get("model", plugins["model"]).mirror_setting
    config = dict(plugins["model_config"])
    if args.hand != "auto":
        if key is None:
            raise HybridfitError(f"--hand {args.hand}: model {plugins['model']} has no mirror setting (one hand only)")
        config[key] = args.hand == "left"
    options = {k: plugins[k] for k in ("objective", "objective_config", "optimizer", "optimizer_config")}
    calibrating = getattr(args, "self_calibrating", False)
    try:
        found = check_setup(data["proposals"], data["confidences"], model=plugins["model"], model_config=config,
                            joint_names=names, try_mirror=args.hand == "auto" and not calibrating, seed=args.seed,
                            search_radius_mm=args.search_radius, **options)
    except HybridfitError:  # the check is advice (an optimiser needing more than its budget, say): the fit
        return config       # itself reports any error of the input or options
    if found.other_hand:
        hand = "right" if found.mirror else "left"
        config[key] = not found.mirror
        warnings.warn(f"{args.proposals}: the proposals are of the {hand} hand (its fit lies a median "
                      f"{np.median(found.mirrored_mm):.1f} mm from the top proposals on {len(found.frames)} frames, "
                      f"the other hand's {np.median(found.distance_mm):.1f} mm): fitting the {hand} hand "
                      f"(--hand {hand}; --hand {'left' if hand == 'right' else 'right'} to keep the other)")
    if found.very_far and not (dataset and args.model_config is None):
        warnings.warn(f"{args.proposals}: the fit lies a median {found.best_mm:.1f} mm from the top proposals on "
                      f"{len(found.frames)} frames, further than any hand's geometry explains: are the joint_names "
                      "those of the proposals, in their order, and the proposals in millimetres?")
    elif found.far and dataset and args.model_config is None and not calibrating:
        sk = skeleton(dataset).dataset
        warnings.warn(f"the fit lies a median {found.best_mm:.1f} mm from the top proposals on {len(found.frames)} "
                      f"frames: the {plugins['model']} model's geometry does not match the {sk} annotations; "
                      f"calibrate it first: hybridfit calibrate --dataset {dataset} --ground-truth LABELS --model "
                      f"{plugins['model']} --out {sk}-{plugins['model']}.toml, then fit with --model-config {sk}-{plugins['model']}.toml")
    return config


def wants_calibration(args, data: dict, dataset: str | None) -> bool:
    """Whether to self-calibrate the skeleton (``--calibrate``; auto: a real data set's
    proposals, no --model-config, at least AUTO_MIN_FRAMES frames with proposals for
    CONFIDENT_POINTS of their points)."""
    if args.calibrate != "auto":
        return args.calibrate == "self"
    if not dataset or args.model_config is not None:
        return False
    top, share = top_proposals(data["proposals"], data["confidences"])
    eligible = int(((share > 0).mean(1) >= CONFIDENT_POINTS).sum())
    return eligible >= AUTO_MIN_FRAMES


def calibrate_skeleton(args, data: dict, names, plugins: dict, dataset: str | None) -> dict:
    """The model settings with the skeleton self-calibrated on the proposals
    (:func:`hybridfit.fitting.calibrate.self_calibrate`, as `hybridfit calibrate --proposals`
    does with the same options); one line on stderr says so and how to keep it."""
    model, config = plugins["model"], dict(plugins["model_config"])
    key = registry.get("model", model).mirror_setting
    mirror = None if args.hand == "auto" or key is None else config[key]
    options = {"objective": str(data["objective"])} if "objective" in data else {}  # as `hybridfit calibrate` fits
    names = list(names) if names is not None else list(registry.create("model", model, config).joint_names)
    result = self_calibrate(data["proposals"], data["confidences"], names, model=model, model_config=config,
                            mirror=mirror, budget=args.budget, seed=args.seed, jobs=args.jobs, fit_options=options,
                            progress=sys.stderr.isatty())
    keep = f"{Path(args.proposals).stem}-{model}.toml"
    command = " ".join(["hybridfit calibrate --proposals", args.proposals]
                       + ([f"--dataset {args.dataset}"] if args.dataset else [])
                       + ([f"--model {model}"] if args.model else [])
                       + ([f"--model-config {args.model_config}"] if args.model_config else [])
                       + ([f"--hand {args.hand}"] if args.hand != "auto" else [])
                       + ([f"--budget {args.budget}"] if args.budget != 3400 else [])
                       + ([f"--seed {args.seed}"] if args.seed else [])
                       + [f"--out {keep}"])
    hand = "" if key is None else f"{'left' if result.settings[key] else 'right'}-hand "
    print(f"hybridfit: the {hand}{model} skeleton was self-calibrated on {len(result.frames)} frames of the proposals "
          f"(its fit {result.residual_before:.1f} -> {result.residual_after:.1f} mm from the top proposals, median); "
          f"to keep it: {command}, then fit with --model-config {keep} (--calibrate none: the model as configured)",
          file=sys.stderr)
    return result.settings


def depth_frames(args, indices: np.ndarray, named: bool) -> dict:
    """observations (and first_params for --first-frame ground-truth) from --depth: of the
    frames ``indices`` of the data set (``named``: the proposals file names them; else all of
    it, frame for frame)."""
    if args.depth is None:
        if args.first_frame == "ground-truth":
            raise HybridfitError("--first-frame ground-truth needs --depth DIR (the data set's model parameters)")
        return {}
    what = "the data-set folder the proposals were made from (`hybridfit synth test --out DIR` writes one)"
    if not Path(args.depth).is_dir():
        kind = "no such folder" if not Path(args.depth).exists() else "a file, not a folder"
        raise HybridfitError(f"--depth {args.depth}: {kind}; --depth takes {what}")
    try:
        ds = load_dataset(args.depth)
    except HybridfitError as err:
        raise HybridfitError(f"--depth {args.depth}: {err}; --depth takes {what}") from None
    if named and len(indices) and indices.max() >= len(ds):
        raise HybridfitError(f"--depth {args.depth}: {len(ds)} frames, but the proposals are of its frames "
                             f"{indices.min()}-{indices.max()} (their file's frames)")
    if not named and len(ds) != len(indices):
        raise HybridfitError(f"--depth {args.depth}: {len(ds)} frames, but the proposals have {len(indices)}")
    out = {"observations": dataset_observations(ds, indices, args.depth)}
    if args.first_frame == "ground-truth":
        if ds.params.shape[1] == 0:
            raise HybridfitError(f"--depth {args.depth}: labels.npz has no model parameters for --first-frame "
                                 "ground-truth")
        out["first_params"] = ds.params[indices[0]]
    return out


def report_failures(errors: dict[int, str], limit: int = 10) -> None:
    """The failed frames and why, at most ``limit`` lines, then a count, on stderr."""
    items = sorted((f, m) for f, m in errors.items() if m != "interrupted")
    for f, msg in items[:limit]:
        print(f"  frame {f}: {msg}", file=sys.stderr)
    if len(items) > limit:
        print(f"  ... and {len(items) - limit} more failed frames", file=sys.stderr)
