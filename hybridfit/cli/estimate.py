"""``hybridfit estimate``: depth frames -> forest proposals -> fitted hand poses."""

from __future__ import annotations

import sys

import numpy as np

from ..datasets import open_dataset
from ..datasets.protocol import ground_truth, model_config
from ..errors import EXIT_INCOMPLETE, EXIT_INTERRUPTED, EXIT_OK
from ..fitting.estimator import EMPTY_FRAME, HybridEstimator
from ..io import save_npz
from ..metrics import summary
from ._common import add_fit_options, add_plugin_options, declare_paths, plugin_kwargs
from ._forest import frame_indices, report_empty
from .fit import report_failures
from .propose import add_proposal_options


def register(sub) -> None:
    p = sub.add_parser("estimate", help="hand poses from depth frames: forest proposals + model fitting")
    p.add_argument("forest", help="forest file (.npz from `hybridfit train`)")
    p.add_argument("data", help="data-set folder")
    p.add_argument("--out", required=True, help="output npz (camera coordinates, mm): the `hybridfit fit` keys plus "
                   "proposals, confidences, empty, frames")
    add_proposal_options(p)
    add_plugin_options(p)
    add_fit_options(p)
    declare_paths(p, inputs=("forest", "data", "--model-config", "--objective-config", "--optimizer-config"),
                  outputs=("--out",))
    p.set_defaults(func=run)


def run(args) -> int:
    plugins = plugin_kwargs(args)
    ds = open_dataset(args.data)
    plugins["model_config"] = model_config(ds, plugins["model"], plugins["model_config"])
    est = HybridEstimator(args.forest, k=args.k, proposal_set=args.proposal_set, stride=args.stride,
                          bandwidth_mm=args.bandwidth, budget=args.budget, seed=args.seed, jobs=args.jobs,
                          search_radius_mm=args.search_radius, **plugins)
    est.get_forest()
    idx = frame_indices(ds, args.frames)
    result = est.estimate_dataset(ds, idx, args.foreground, progress=sys.stderr.isatty())
    fit = result.fit
    out = {**fit.to_npz(), "proposals": result.proposals.proposals, "confidences": result.proposals.confidences,
           "empty": result.proposals.empty, "frames": idx}
    if ds.dataset:
        out["dataset"] = np.asarray(ds.dataset)
    gt = ground_truth(ds, idx)
    if gt is not None and gt.shape == fit.joints.shape:
        out["ground_truth"] = gt
    save_npz(args.out, **out)
    F = len(idx)
    print(f"estimated {F - int(fit.failed.sum())}/{F} frames -> {args.out}")
    report_empty(result.proposals.empty, idx, sys.stderr)
    report_failures({int(idx[f]): m for f, m in fit.errors.items() if m != EMPTY_FRAME})
    if "ground_truth" in out and (~fit.failed).any():
        s = summary(fit.joints[~fit.failed], gt[~fit.failed])
        print("fitted: mean joint error {mean_error_mm:.2f} mm; success rate @20/40/80 mm: "
              "{success@20mm:.3f} / {success@40mm:.3f} / {success@80mm:.3f}".format(**s))
    if fit.interrupted:
        print(f"interrupted: finished frames saved to {args.out}", file=sys.stderr)
        return EXIT_INTERRUPTED
    return EXIT_INCOMPLETE if fit.failed.any() else EXIT_OK
