"""Speed of the core on one core: objective throughput, stepwise PSO per frame, ours vs pymoo.

    NUMBA_NUM_THREADS=1 python benchmarks/bench_core.py [--frames 200]

Prints (medians; the machine is shared, so ratios are the robust figures):
1. batched forward kinematics + clamped-confidence objective, hypotheses per second
   (21 joints, k = 3);
2. one frame fitted by stepwise PSO at budget 3400, milliseconds;
3. our PSO against pymoo's PSO, both run stage by stage by the same stepwise wrapper with
   the same stage budgets and swarm sizes, on the same synthetic frames: time per frame
   (ratio) and mean joint error;
4. start-up: a fresh process's first fit, twice (the second reads numba's cache).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

import hybridfit
from hybridfit.metrics import joint_errors
from hybridfit.optimizer import Optimizer, Task
from hybridfit.problem import Problem

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from _util import median_time, table  # noqa: E402


class PymooPSO(Optimizer):
    """pymoo's PSO on a task: a square swarm, as many whole generations as the budget allows."""

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        from pymoo.algorithms.soo.nonconvex.pso import PSO
        from pymoo.core.problem import Problem as PymooProblem
        from pymoo.optimize import minimize

        class Wrapped(PymooProblem):
            def __init__(self):
                super().__init__(n_var=task.dim, n_obj=1, xl=task.lower, xu=task.upper)

            def _evaluate(self, X, out, *args, **kwargs):
                out["F"] = task.evaluate(X)[:, None]

        pop = max(2, int(round(np.sqrt(task.budget))))
        minimize(Wrapped(), PSO(pop_size=pop), ("n_gen", task.budget // pop), seed=int(rng.integers(2**31)),
                 verbose=False)


def throughput(problem: Problem, n: int = 10_000) -> float:
    rng = np.random.default_rng(0)
    X = problem.x0 + rng.normal(0, 0.05, (n, problem.x0.size))
    problem.evaluate(X)
    return n / median_time(lambda: problem.evaluate(X), repeat=9)


def fit_frames(data, optimizer, budget=3400):
    model = hybridfit.create("model", "hand26")
    objective = hybridfit.create("objective", "clamped-confidence")
    times, errors = [], []
    for f in range(len(data["proposals"])):
        t = time.process_time()  # CPU time: robust to other jobs on a shared machine
        problem = Problem(model, objective, data["proposals"][f], data["confidences"][f])
        result = optimizer.run(problem, budget, np.random.default_rng([0, f]))
        times.append(time.process_time() - t)
        errors.append(joint_errors(model.forward(result.params), data["ground_truth"][f]).mean())
    return float(np.median(times)), float(np.mean(errors))


def startup() -> list[float]:
    """Import + first fit in two fresh processes sharing a new, empty numba cache folder:
    the first compiles the kernels, the second reads them from the cache."""
    code = ("import time; t = time.perf_counter(); import hybridfit; "
            "d = hybridfit.synthetic_proposals(1); hybridfit.fit(d['proposals'], d['confidences']); "
            "print(time.perf_counter() - t)")
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "NUMBA_CACHE_DIR": cache}
        return [float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                                     env=env).stdout) for _ in range(2)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    args = parser.parse_args()
    data = hybridfit.synthetic_proposals(args.frames, k=3, seed=2015)
    model = hybridfit.create("model", "hand26")
    objective = hybridfit.create("objective", "clamped-confidence")
    problem = Problem(model, objective, data["proposals"][0], data["confidences"][0])

    rate = throughput(problem)
    ours = hybridfit.create("optimizer", "stepwise-pso")
    fit_frames({k: v[:3] for k, v in data.items()}, ours)  # compile
    ours_time, ours_error = fit_frames(data, ours)
    pymoo = hybridfit.create("optimizer", "stepwise").with_params()
    pymoo.inner = PymooPSO()  # same stepwise wrapper, pymoo's PSO per stage
    pymoo_time, pymoo_error = fit_frames(data, pymoo)
    first, second = startup()
    top1 = joint_errors(data["proposals"][:, :, 0], data["ground_truth"]).mean()

    print(f"## Core speed ({args.frames} synthetic frames, k = 3, budget 3400, one core)\n")
    print(table(["measure", "value"], [
        ["forward kinematics + objective, hypotheses/s", f"{rate:,.0f}"],
        ["stepwise PSO, CPU ms per frame (median)", f"{ours_time * 1e3:.2f}"],
        ["pymoo PSO in the same stepwise wrapper, CPU ms per frame (median)", f"{pymoo_time * 1e3:.2f}"],
        ["speed-up of ours over pymoo", f"{pymoo_time / ours_time:.1f}x"],
        ["mean joint error, ours (mm)", f"{ours_error:.2f}"],
        ["mean joint error, pymoo (mm)", f"{pymoo_error:.2f}"],
        ["mean joint error, top-1 proposals (mm)", f"{top1:.2f}"],
        ["fresh process, import + first fit (s): compiling / from numba's cache", f"{first:.2f} / {second:.2f}"],
    ]))


if __name__ == "__main__":
    main()
