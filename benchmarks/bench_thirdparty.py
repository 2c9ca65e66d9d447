"""Third-party plugins against the built-ins, on one core, through ``hybridfit.fit`` end to end.

    python benchmarks/bench_thirdparty.py [--frames 200 --budget 3400 --repeat 5 --cpu 0]
                                          [--json benchmarks/results/thirdparty.json]

Pins itself to one core (``--cpu``, as ``taskset -c 0`` would) and fits the same synthetic
frames (k = 3) with each of these, a round of each after the other (so a load that changes
during the run hits all alike), timing CPU per frame:

- objective: ``clamped-point`` (``examples/hybridfit-numpy-objective``, the paper's formula
  as a per-point numba function) against the built-in ``clamped-confidence``;
- optimizer: ``numpy-pso`` (``examples/hybridfit-numpy-pso``, batch steps in plain numpy)
  against the built-in ``pso``, both inside ``stepwise`` (refine_share 0.25);
- bind-only: a plain numpy ``bind`` written with few numpy calls (:class:`FewCalls`) against
  the built-in ``clamped-confidence``;
- naive bind: ``numpy-clamped`` (the example's ten-line numpy ``bind``) likewise.

Each ratio is the median over rounds of the third-party time over the built-in's in the same
round. The last line reads ``objective Ax, optimizer Bx, bind-only Cx``, the line before it
the naive bind's ratio. The figures go to ``--json`` (the results page's record).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for example in ("hybridfit-numpy-objective", "hybridfit-numpy-pso"):
    sys.path.insert(0, str(ROOT / "examples" / example / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import hybridfit  # noqa: E402
from _util import json_argument, table_record, write_record  # noqa: E402
from hybridfit.objective import Objective  # noqa: E402
from hybridfit_numpy_objective import ClampedPoint, NumpyClamped  # noqa: E402
from hybridfit_numpy_pso import NumpyPSO  # noqa: E402


class FewCalls(Objective):
    """The paper's objective as a plain numpy ``bind`` in few numpy calls: each term
    w (d^2 / d_max^2 - 1) is linear in (x, y, z, x^2, y^2, z^2, 1) of the point, so one batched
    matmul of per-point coefficients (made once per point set) scores every proposal."""

    Settings = ClampedPoint.Settings

    def bind(self, proposals, weights):
        ws = weights / self.settings.d_max_mm**2
        A = np.concatenate([-2 * ws[..., None] * proposals, np.repeat(ws[..., None], 3, -1),
                            (ws * (proposals**2).sum(-1) - weights)[..., None]], axis=-1)  # (Q, K, 7)
        cut = {}

        def loss(points, subset):
            key = subset.tobytes()
            if key not in cut:
                cut[key] = np.ascontiguousarray(A[subset])
            h = points[:, subset].transpose(1, 2, 0)  # (m, 3, N)
            rows = np.concatenate((h, h * h, np.ones((len(subset), 1, len(points)))), axis=1)  # (m, 7, N)
            return np.minimum.reduce(cut[key] @ rows, axis=1, initial=0.0).sum(axis=0)

        return loss


def stepwise(inner_class):
    """``stepwise`` (refine_share 0.25) running an unregistered optimiser class."""
    from hybridfit_plugins.optimizers.stepwise import Stepwise

    class StepwiseOf(Stepwise):
        inner = refiner = property(lambda self: inner_class())

    return StepwiseOf(optimizer="pso", refine_share=0.25)


#: row: (built-in plugins, third-party plugins), as hybridfit.fit's keywords
ROWS = {
    "objective": (dict(objective="clamped-confidence"), dict(objective=ClampedPoint())),
    "optimizer": (dict(optimizer="stepwise", optimizer_config={"optimizer": "pso", "refine_share": 0.25}),
                  dict(optimizer=stepwise(NumpyPSO))),
    "bind-only": (dict(objective="clamped-confidence"), dict(objective=FewCalls())),
    "naive bind": (dict(objective="clamped-confidence"), dict(objective=NumpyClamped())),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--budget", type=int, default=3400)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--cpu", type=int, default=0, help="the core to run on")
    json_argument(parser, "thirdparty")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {args.cpu})
    data = hybridfit.synthetic_proposals(args.frames, k=3, seed=11)
    runs = {(row, side): (lambda p=plugins: hybridfit.fit(data["proposals"], data["confidences"], budget=args.budget,
                                                          seed=0, **p))
            for row, pair in ROWS.items() for side, plugins in zip(("built-in", "third-party"), pair)}
    error = {key: float(np.linalg.norm(run().model_joints - data["ground_truth"], axis=-1).mean())  # compiles, loads
             for key, run in runs.items()}
    seconds = {key: [] for key in runs}
    for _ in range(args.repeat):
        for key, run in runs.items():
            start = time.process_time()
            run()
            seconds[key].append(time.process_time() - start)
    ms = {key: 1e3 * float(np.median(s)) / args.frames for key, s in seconds.items()}
    ratio = {row: float(np.median(np.divide(seconds[row, "third-party"], seconds[row, "built-in"]))) for row in ROWS}
    print(f"{args.frames} synthetic frames, budget {args.budget}, one core (CPU {args.cpu}), CPU ms per frame "
          f"(median of {args.repeat}), mean joint error mm")
    rows = []
    for row in ROWS:
        cells = [row, ms[row, "built-in"], error[row, "built-in"], ms[row, "third-party"], error[row, "third-party"],
                 f"{ratio[row]:.2f}x"]
        rows.append(cells)
        print(f"{row:10s} built-in {cells[1]:6.3f} ms ({cells[2]:.2f} mm)   third-party {cells[3]:6.3f} ms "
              f"({cells[4]:.2f} mm)   {cells[5]}")
    print(f"naive bind {ratio['naive bind']:.1f}x")
    print(f"objective {ratio['objective']:.1f}x, optimizer {ratio['optimizer']:.1f}x, "
          f"bind-only {ratio['bind-only']:.1f}x")
    header = ["comparison", "built-in ms/frame", "built-in error mm", "third-party ms/frame", "third-party error mm",
              "ratio"]
    write_record(args.json, {"thirdparty": table_record(header, rows)},
                 figures={"frames": args.frames, "budget": args.budget, "repeat": args.repeat,
                          "ms_per_frame": {f"{row} {side}": v for (row, side), v in ms.items()},
                          "ratio": ratio})


if __name__ == "__main__":
    main()
