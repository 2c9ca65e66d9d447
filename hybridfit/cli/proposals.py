"""``hybridfit proposals from-results``: published predictions as proposals for fitting."""

from __future__ import annotations

from ..datasets.results import frames_of, is_keypoints, read_keypoints, read_proposals
from ..errors import HybridfitError
from ..io import frame_slice, save_npz
from ._common import add_frames_option, add_keypoint_options, declare_paths


def register(sub) -> None:
    p = sub.add_parser("proposals", help="make proposal files from other data")
    kinds = p.add_subparsers(dest="proposals_command", metavar="SOURCE", required=True)
    q = kinds.add_parser("from-results", help="results files (common format) -> one proposal per joint per file")
    q.add_argument("results", nargs="+", metavar="FILE", help="results files: one line per frame, J x (u, v, d); or "
                   "one MediaPipe results JSON or OpenPose keypoints folder (or *_keypoints.json)")
    q.add_argument("--dataset", help="skeleton and camera convention of results files (required for them): icvl, "
                   "nyu, nyu36, msra, mediapipe, mano or a skeleton .toml file")
    q.add_argument("--hand", choices=("auto", "right", "left"), default="auto",
                   help="MediaPipe and OpenPose keypoints: the hand to read (default auto: the one the file shows best)")
    add_keypoint_options(q)
    q.add_argument("--confidences", nargs="+", type=float, metavar="C",
                   help="one non-negative confidence per file (default: per point from the files' agreement: "
                   "with three or more, the inverse of each file's own error variance estimated from the "
                   "differences between files; equal for one or two)")
    q.add_argument("--ground-truth", metavar="LABELS", help="ground truth in the same format, stored for evaluation")
    add_frames_option(q, "frames to keep")
    q.add_argument("--out", required=True, help="output npz: proposals (F,J,k,3) mm (camera coordinates), "
                   "confidences, joint_names, dataset, objective, ground_truth")
    declare_paths(q, inputs=("results", "--ground-truth"), outputs=("--out",))
    q.set_defaults(func=run_from_results)


def run_from_results(args) -> int:
    if any(is_keypoints(f) for f in args.results):
        if len(args.results) > 1:
            raise HybridfitError(f"one MediaPipe or OpenPose input at a time, got {len(args.results)}: "
                                 f"{', '.join(args.results)}")
        for option, value in (("--dataset", args.dataset), ("--confidences", args.confidences),
                              ("--ground-truth", args.ground_truth)):
            if value is not None:
                raise HybridfitError(f"{option} applies to results files, not to {args.results[0]} (MediaPipe and "
                                     "OpenPose keypoints are the mediapipe skeleton's, with their own confidences)")
        out = read_keypoints(args.results[0], hand=None if args.hand == "auto" else args.hand,
                             mirrored=args.mirrored, labels=args.labels, unit=args.unit)
    elif args.dataset is None:
        raise HybridfitError("--dataset is required for results files: icvl, nyu, nyu36, msra, mediapipe, mano or a "
                             "skeleton .toml file")
    else:
        out = read_proposals(args.results, args.dataset, args.confidences, args.ground_truth, "--confidences")
    out = frames_of(out, frame_slice(args.frames, len(out["proposals"])))
    F, J, k, _ = out["proposals"].shape
    save_npz(args.out, **out)
    print(f"wrote {F} frames, {J} points, k={k} -> {args.out}")
    return 0
