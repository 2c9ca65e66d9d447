"""Choice of the clamping distance d_max of the paper's objective (not given in the paper).

    python benchmarks/bench_dmax.py [--frames 150] [--jobs 2]

Fits the same synthetic frames (k = 3, noise 5 mm and decoys) with stepwise PSO at budget
3400 for several d_max and prints mean joint error and success rate at 40 mm.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import hybridfit
from hybridfit.metrics import joint_errors, success_rate

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from _util import table  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--jobs", type=int, default=2)
    args = parser.parse_args()
    data = hybridfit.synthetic_proposals(args.frames, k=3, seed=7)
    rows = []
    for d_max in (10, 20, 30, 40, 60, 80, 120):
        r = hybridfit.fit(data["proposals"], data["confidences"], objective_config={"d_max_mm": d_max},
                          jobs=args.jobs)
        e = joint_errors(r.joints, data["ground_truth"])
        rows.append([d_max, f"{e.mean():.2f}", f"{np.median(e.mean(1)):.2f}", f"{success_rate(e, [40])[0]:.3f}"])
    print(f"## d_max ({args.frames} synthetic frames, k = 3, stepwise PSO, budget 3400)\n")
    print(table(["d_max (mm)", "mean error (mm)", "median frame error (mm)", "success @40 mm"], rows))


if __name__ == "__main__":
    main()
