"""``hybridfit proposals from-results``: published predictions as proposals for fitting."""

from __future__ import annotations

from ..datasets.results import frames_of, read_proposals
from ..io import frame_slice, save_npz
from ._common import add_frames_option, declare_paths


def register(sub) -> None:
    p = sub.add_parser("proposals", help="make proposal files from other data")
    kinds = p.add_subparsers(dest="proposals_command", metavar="SOURCE", required=True)
    q = kinds.add_parser("from-results", help="results files (common format) -> one proposal per joint per file")
    q.add_argument("results", nargs="+", metavar="FILE", help="results files: one line per frame, J x (u, v, d)")
    q.add_argument("--dataset", required=True, help="skeleton and camera convention: icvl, nyu, "
                   "nyu36, msra, mediapipe, mano or a skeleton .toml file")
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
    out = read_proposals(args.results, args.dataset, args.confidences, args.ground_truth, "--confidences")
    out = frames_of(out, frame_slice(args.frames, len(out["proposals"])))
    F, J, k, _ = out["proposals"].shape
    save_npz(args.out, **out)
    print(f"wrote {F} frames, {J} points, k={k} -> {args.out}")
    return 0
