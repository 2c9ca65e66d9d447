"""``hybridfit proposals from-results``: published predictions as proposals for fitting."""

from __future__ import annotations

import numpy as np

from ..datasets.results import proposals_from_results
from ..datasets.skeletons import skeleton
from ..errors import HybridfitError
from ..io import check_output, frame_slice, save_npz
from ._common import read_results


def register(sub) -> None:
    p = sub.add_parser("proposals", help="make proposal files from other data")
    kinds = p.add_subparsers(dest="proposals_command", metavar="SOURCE", required=True)
    q = kinds.add_parser("from-results", help="results files (common format) -> one proposal per joint per file")
    q.add_argument("results", nargs="+", metavar="FILE", help="results files: one line per frame, J x (u, v, d)")
    q.add_argument("--dataset", required=True, help="skeleton and camera convention: icvl, nyu, "
                   "nyu36, msra, mediapipe, mano or a skeleton .toml file")
    q.add_argument("--confidences", nargs="+", type=float, metavar="C",
                   help="one non-negative confidence per file (default: equal)")
    q.add_argument("--ground-truth", metavar="LABELS", help="ground truth in the same format, stored for evaluation")
    q.add_argument("--frames", metavar="START:STOP", help="keep only these frames (default: all)")
    q.add_argument("--out", required=True, help="output npz: proposals (F,J,k,3) mm, confidences, joint_names")
    q.set_defaults(func=run_from_results)


def run_from_results(args) -> int:
    check_output(args.out)
    sk = skeleton(args.dataset)
    xyz = [read_results(f, args.dataset) for f in args.results]
    for f, a in zip(args.results[1:], xyz[1:]):
        if len(a) != len(xyz[0]):
            raise HybridfitError(f"{f}: {len(a)} frames, but {args.results[0]} has {len(xyz[0])}")
    if args.confidences is not None and len(args.confidences) != len(xyz):
        raise HybridfitError(f"--confidences: need {len(xyz)} values (one per file), got {args.confidences}")
    try:
        fused = proposals_from_results(xyz, args.confidences)
    except HybridfitError as err:
        raise HybridfitError(f"--confidences: {err}") from None
    sel = frame_slice(args.frames, len(xyz[0]))
    F, J, k, _ = fused["proposals"][sel].shape
    out = {
        **{key: value[sel] for key, value in fused.items() if key != "objective"},
        "objective": fused["objective"],
        "joint_names": np.asarray(sk.model_names),
        "dataset": np.asarray(sk.dataset),
    }
    if args.ground_truth:
        gt = read_results(args.ground_truth, args.dataset)
        if len(gt) != len(xyz[0]):
            raise HybridfitError(f"{args.ground_truth}: {len(gt)} frames, but the results have {len(xyz[0])}")
        out["ground_truth"] = gt[sel]
    save_npz(args.out, **out)
    print(f"wrote {F} frames, {J} points, k={k} -> {args.out}")
    return 0
