"""The robust-fitting choices on stress data (docs/robust-fitting.md).

Two 60-frame stress sets (seeds 7 and 101) per skeleton, of a subject the model matches in
size (no scale or proportion change, derived-point weights unperturbed, 2 mm annotation
offsets), fitted with k = 3 at budget 3400 (seed 0) by the default ``stepwise-pso`` and by
it with one choice turned off: guide points for an ill-posed root (``min_root_points = 0``)
and the final joint refinement (``refine_share = 0``); the paper's schedule has both off.
Prints the mean joint error in mm per set, with the top-1 proposals beside them.

    python benchmarks/bench_robust.py [--skeletons icvl,nyu,msra] [--jobs 2]

The table also goes to ``--json`` (default ``benchmarks/results/robust.json``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import hybridfit
from hybridfit.datasets.skeletons import dataset_model_config
from hybridfit.metrics import joint_errors

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _util import json_argument, table, table_record, write_record  # noqa: E402

VARIANTS = {
    "default": {},
    "no guide points": {"min_root_points": 0},
    "no final refinement": {"refine_share": 0.0},
    "the paper's schedule": {"refine_share": 0.0, "min_root_points": 0, "min_root_lever_mm": 0.0},
}
SETS = (7, 101)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--skeletons", default="icvl,nyu,msra")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--jobs", type=int, default=1)
    json_argument(ap, "robust")
    args = ap.parse_args()
    rows = []
    for skeleton in args.skeletons.split(","):
        model_config = dataset_model_config("hand26", {}, skeleton)
        for seed in SETS:
            z = hybridfit.stress_proposals(args.frames, dataset=skeleton, seed=seed, scale_range=(1.0, 1.0),
                                           proportion_sd=0.0, weight_sd=0.0, offset_mm=2.0)
            names = [str(n) for n in z["joint_names"]]
            error = lambda joints: float(np.nanmean(joint_errors(joints, z["ground_truth"])))  # noqa: E731
            row = [skeleton, seed, error(z["proposals"][:, :, 0])]
            for config in VARIANTS.values():
                fit = hybridfit.fit(z["proposals"], z["confidences"], joint_names=names, model_config=model_config,
                                    budget=3400, optimizer_config=config, seed=0, jobs=args.jobs)
                row.append(error(fit.joints))
            rows.append(row)
            print(f"{skeleton} set {seed}: done", flush=True)
    header, cells = ["skeleton", "set (seed)", "top-1", *VARIANTS], [[*r[:2], *(f"{v:.2f}" for v in r[2:])] for r in rows]
    print(table(header, cells))
    write_record(args.json, {"robust": table_record(header, cells)})


if __name__ == "__main__":
    main()
