"""Third-party plugins against the built-ins, on one core, through ``hybridfit.fit`` end to end.

    python benchmarks/bench_thirdparty.py [--frames 200 --budget 3400 --repeat 5 --cpu 0]

Pins itself to one core (``--cpu``, as ``taskset -c 0`` would) and prints medians of CPU time
per frame, with the mean joint error of each fit (synthetic frames, k = 3), timing the built-in
and the third-party fit alternately (so a load that changes during the run hits both), for:

1. objective: the plain-numpy ``numpy-clamped`` example (``examples/hybridfit-numpy-objective``,
   the paper's formula with the frame-batched ``score_frames`` capability) against the
   built-in ``clamped-confidence`` (a compiled kernel), both under ``stepwise-pso``;
2. optimizer: the plain-numpy ``numpy-pso`` example (``examples/hybridfit-numpy-pso``, ask/tell
   batch steps) against the built-in ``pso`` (numba steps), both inside ``stepwise`` with the
   default schedule (refine_share 0.25), objective ``clamped-confidence``;
3. bind-only: the same numpy objective offering ``bind`` only (no batching over frames)
   against the built-in ``clamped-confidence``.

The last line reads ``objective 1.8x, optimizer 1.9x, bind-only 5.2x``: each third-party
time over the built-in's.
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
from hybridfit.objective import Objective  # noqa: E402
from hybridfit_numpy_objective import NumpyClamped  # noqa: E402
from hybridfit_numpy_pso import NumpyPSO  # noqa: E402



class BindOnly(Objective):
    """``numpy-clamped`` without its frame-batched capability: ``bind`` only."""

    Settings = NumpyClamped.Settings
    bind = NumpyClamped.bind
    lower_bound = NumpyClamped.lower_bound


def measure(data, budget: int, repeat: int, *plugins: dict) -> list[tuple[float, float]]:
    """For each set of plugins: (CPU ms per frame, median over ``repeat`` fits; mean joint
    error mm). The sets' fits alternate."""
    runs = [lambda p=p: hybridfit.fit(data["proposals"], data["confidences"], budget=budget, seed=0, **p)
            for p in plugins]
    errors = [float(np.linalg.norm(run().model_joints - data["ground_truth"], axis=-1).mean())  # compiles or loads
              for run in runs]
    seconds = [[] for _ in runs]
    for _ in range(repeat):
        for run, out in zip(runs, seconds):
            start = time.process_time()
            run()
            out.append(time.process_time() - start)
    return [(1e3 * float(np.median(s)) / len(data["proposals"]), e) for s, e in zip(seconds, errors)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--budget", type=int, default=3400)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--cpu", type=int, default=0, help="the core to run on")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {args.cpu})
    data = hybridfit.synthetic_proposals(args.frames, k=3, seed=11)
    stepwise = lambda inner: {"optimizer": "stepwise", "optimizer_config": {"optimizer": inner, "refine_share": 0.25}}  # noqa: E731
    rows = {
        "objective": (dict(objective="clamped-confidence"), dict(objective=NumpyClamped())),
        "optimizer": (stepwise("pso"), {**stepwise("pso"), "optimizer_config": None, "optimizer": _stepwise(NumpyPSO)}),
        "bind-only": (dict(objective="clamped-confidence"), dict(objective=BindOnly())),
    }
    ratios = []
    print(f"{args.frames} synthetic frames, budget {args.budget}, one core (CPU {args.cpu}), CPU ms per frame (median of "
          f"{args.repeat}), mean joint error mm")
    for name, (built_in, third_party) in rows.items():
        (t_ref, e_ref), (t, e) = measure(data, args.budget, args.repeat, built_in, third_party)
        print(f"{name:10s} built-in {t_ref:6.3f} ms ({e_ref:.2f} mm)   third-party {t:6.3f} ms ({e:.2f} mm)   "
              f"{t / t_ref:.2f}x")
        ratios.append(f"{name} {t / t_ref:.1f}x")
    print(", ".join(ratios))


def _stepwise(inner_class):
    """``stepwise`` (default schedule, refine_share 0.25) running an unregistered optimiser
    class: its plan's stages name instances of it."""
    from hybridfit_plugins.optimizers.stepwise import Stepwise

    class StepwiseOf(Stepwise):
        @property
        def inner(self):
            return inner_class()

        @property
        def refiner(self):
            return inner_class()

    return StepwiseOf(optimizer="pso", refine_share=0.25)


if __name__ == "__main__":
    main()
