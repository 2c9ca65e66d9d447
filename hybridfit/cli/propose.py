"""``hybridfit propose``: joint proposals with confidences from a forest (a `hybridfit fit` input)."""

from __future__ import annotations

import sys

import numpy as np

from ..datasets import open_dataset
from ..datasets.protocol import ground_truth
from ..fitting.estimator import HybridEstimator
from ..errors import EXIT_INCOMPLETE, EXIT_OK
from ..io import save_npz
from ..metrics import joint_errors, oracle
from ._common import add_frames_option, declare_paths, positive_float, positive_int
from ._forest import frame_indices, report_empty


def add_proposal_options(p) -> None:
    g = p.add_argument_group("proposals")
    g.add_argument("-k", type=positive_int, default=3, help="proposals per joint (default 3)")
    g.add_argument("--proposal-set", type=positive_int, default=200, help="|P~|: most confident votes per joint for mean-shift (default 200)")
    g.add_argument("--stride", type=positive_int, default=2, help="pixel grid step of the dense sampling (default 2)")
    g.add_argument("--bandwidth", type=positive_float, default=10.0, help="mean-shift bandwidth, mm (default 10)")
    g.add_argument("--foreground", choices=("auto", "labels", "depth", "segment"), default="auto",
                   help="hand pixels: part labels, depth > 0, or nearest-object segmentation (default auto: labels if the data has them)")
    add_frames_option(g, "frames to use")


def register(sub) -> None:
    p = sub.add_parser("propose", help="joint proposals from a forest (-> proposals .npz, a `hybridfit fit` input)")
    p.add_argument("forest", help="forest file (.npz from `hybridfit train`)")
    p.add_argument("data", help="data-set folder")
    p.add_argument("--out", required=True, help="output npz: proposals (camera coordinates, mm), confidences, "
                   "joint_names, empty, frames, ground_truth, dataset (the skeleton, for real datasets)")
    add_proposal_options(p)
    declare_paths(p, inputs=("forest", "data"), outputs=("--out",))
    p.set_defaults(func=run)


def run(args) -> int:
    est = HybridEstimator(args.forest, k=args.k, proposal_set=args.proposal_set, stride=args.stride,
                          bandwidth_mm=args.bandwidth)
    est.get_forest()  # a bad forest file fails before the data is read
    ds = open_dataset(args.data)
    idx = frame_indices(ds, args.frames)
    props = est.propose_dataset(ds, idx, args.foreground, progress=sys.stderr.isatty())
    out = {"proposals": props.proposals, "confidences": props.confidences,
           "joint_names": np.asarray(props.joint_names), "empty": props.empty, "frames": idx}
    if ds.dataset:
        out["dataset"] = np.asarray(ds.dataset)
    gt = ground_truth(ds, idx)
    if gt is not None and gt.shape == props.proposals.shape[:2] + (3,):
        out["ground_truth"] = gt
    save_npz(args.out, **out)
    print(f"proposals for {len(idx)} frames (k={args.k}, |P~|={args.proposal_set}) -> {args.out}")
    report_empty(props.empty, idx, sys.stderr)
    if "ground_truth" in out and (~props.empty).any():
        ok = ~props.empty
        top = joint_errors(props.proposals[ok, :, 0], gt[ok]).mean()
        best = joint_errors(oracle(props.proposals[ok], gt[ok]), gt[ok]).mean()
        print(f"mean joint error: top proposal {top:.2f} mm, oracle (best of k) {best:.2f} mm")
    return EXIT_INCOMPLETE if len(idx) and props.empty.all() else EXIT_OK  # some empty frames: listed, not a failure
