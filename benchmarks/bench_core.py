"""Speed of the core on one core: scoring throughput, fitting per frame, its spread over
seeds, --jobs scaling and start-up.

    python benchmarks/bench_core.py [--frames 200 --seeds 20]

Prints (medians of CPU time, so other jobs on a shared machine disturb little):
1. ``Problem.evaluate`` (the model's forward kinematics and clamped-confidence's bound loss),
   hypotheses per second at batches of 64 and 1000 (21 joints, k = 3);
2. stepwise PSO per frame at budgets 1000 and 3400, with the default schedule (a final joint
   refinement, ``refine_share`` 0.25) and the paper's (none): the driver's run of one chunk
   alone, ``hybridfit.fit`` end to end (problem set-up included) and one frame at a time
   through the same driver (``run_problem``: a group of one, as tracking runs);
3. the mean joint error over ``--seeds`` seeds x ``--frames`` frames, and its seed-to-seed sd;
4. ``hybridfit.fit`` with ``--jobs`` 1 and 2 (threads), wall time (without taskset);
5. start-up: a fresh process's import + first fit, compiling and from numba's cache.

The table also goes to ``--json`` (default ``benchmarks/results/core.json``).
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
from hybridfit.fitting import driver, frames as fitting
from hybridfit.metrics import joint_errors
from hybridfit.problem import Problem

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from _util import json_argument, median_time, table, table_record, write_record  # noqa: E402


def throughput(problem: Problem, n: int) -> float:
    """Hypotheses per CPU second of problem.evaluate on batches of n."""
    rng = np.random.default_rng(0)
    X = problem.x0 + rng.normal(0, 0.05, (n, problem.x0.size))
    problem.evaluate(X)
    reps = max(1, 20_000 // n)
    return n * reps / median_time(lambda: [problem.evaluate(X) for _ in range(reps)], repeat=9, clock=time.process_time)


#: stepwise-pso's default schedule (a final joint refinement) and the paper's (none)
SCHEDULES = {"default": {}, "paper": {"refine_share": 0.0}}


def stepwise_pso(schedule: str = "default"):
    """stepwise-pso with a schedule."""
    return hybridfit.create("optimizer", "stepwise-pso", SCHEDULES[schedule])


def one_at_a_time(data, budget: int, schedule: str = "default") -> float:
    """Median CPU seconds per frame of ``run_problem`` (the driver on a group of one frame)."""
    model = hybridfit.create("model", "hand26")
    objective = hybridfit.create("objective", "clamped-confidence")
    problems = [Problem(model, objective, p, c) for p, c in zip(data["proposals"], data["confidences"])]
    times = []
    for f, problem in enumerate(problems):
        t = time.process_time()
        driver.run_problem(stepwise_pso(schedule), problem, budget, 0, f)
        times.append(time.process_time() - t)
    return float(np.median(times))


def driver_call(data, budget: int, schedule: str = "default") -> float:
    """CPU seconds per frame of the driver's run alone (set-up excluded)."""
    model = hybridfit.create("model", "hand26")
    objective = hybridfit.create("objective", "clamped-confidence")
    fitter = driver.Driver(model, objective, stepwise_pso(schedule), model.joint_names, budget, 0)
    chunk = fitter.prepare(range(len(data["proposals"])), data["proposals"], data["confidences"])
    fitter.run(chunk)
    return median_time(lambda: fitter.run(chunk), repeat=7, clock=time.process_time) / len(chunk.kept)


def fit_time(data, budget: int, jobs: int = 1, clock=time.process_time, schedule: str = "default") -> float:
    """Seconds per frame of hybridfit.fit (end to end)."""
    return median_time(lambda: hybridfit.fit(data["proposals"], data["confidences"], budget=budget, jobs=jobs,
                                             optimizer_config=SCHEDULES[schedule]),
                       repeat=5, clock=clock) / len(data["proposals"])


def startup() -> list[float]:
    """Import + first fit of one frame (read from a file) in two fresh processes sharing a new,
    empty numba cache folder: the first compiles the kernels, the second reads them from the cache."""
    with tempfile.TemporaryDirectory() as folder:
        frames = os.path.join(folder, "frames.npz")
        np.savez(frames, **hybridfit.synthetic_proposals(1))
        code = ("import time; t = time.perf_counter(); import numpy, hybridfit; "
                f"d = numpy.load({frames!r}); hybridfit.fit(d['proposals'], d['confidences']); "
                "print(time.perf_counter() - t)")
        env = {**os.environ, "NUMBA_CACHE_DIR": os.path.join(folder, "cache")}
        return [float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                                     env=env).stdout) for _ in range(2)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--seeds", type=int, default=20, help="seeds of the error's spread")
    json_argument(parser, "core")
    args = parser.parse_args()
    data = hybridfit.synthetic_proposals(args.frames, k=3, seed=2015)
    model = hybridfit.create("model", "hand26")
    objective = hybridfit.create("objective", "clamped-confidence")
    problem = Problem(model, objective, data["proposals"][0], data["confidences"][0])
    hybridfit.fit(data["proposals"][:2], data["confidences"][:2])  # compile

    rows = [[f"forward kinematics + objective, batch {n}, hypotheses/s", f"{throughput(problem, n):,.0f}"]
            for n in (64, 1000)]
    small = {k: v[:40] for k, v in data.items()}
    chunk = {k: v[:fitting.CHUNK] for k, v in data.items()}
    for schedule in SCHEDULES:
        for budget in (1000, 3400):
            name = f"stepwise PSO @{budget}, {schedule} schedule"
            rows += [
                [f"{name}, driver run (one chunk), CPU ms/frame", f"{driver_call(chunk, budget, schedule) * 1e3:.3f}"],
                [f"{name}, hybridfit.fit end to end, CPU ms/frame",
                 f"{fit_time(data, budget, schedule=schedule) * 1e3:.3f}"],
                [f"{name}, one frame at a time (run_problem), CPU ms/frame",
                 f"{one_at_a_time(small, budget, schedule) * 1e3:.3f}"],
            ]
    errors = [joint_errors(model.forward(hybridfit.fit(data["proposals"], data["confidences"], seed=seed).params),
                           data["ground_truth"]).mean() for seed in range(args.seeds)]
    rows.append([f"mean joint error over {args.seeds} seeds x {args.frames} frames (mm)",
                 f"{np.mean(errors):.3f} (seed-to-seed sd {np.std(errors, ddof=1):.4f})"])
    one = fit_time(data, 3400, 1, time.perf_counter)
    two = fit_time(data, 3400, 2, time.perf_counter)
    rows.append(["hybridfit.fit --jobs 1 / 2, wall ms/frame (speed-up)", f"{one * 1e3:.3f} / {two * 1e3:.3f} ({one / two:.2f}x)"])
    first, second = startup()
    rows.append(["fresh process, import + first fit (s): compiling / from numba's cache", f"{first:.2f} / {second:.2f}"])
    print(f"## Core speed (synthetic frames, k = 3, one core unless said)\n")
    print(table(["measure", "value"], rows))
    write_record(args.json, {"core": table_record(["measure", "value"], rows)})


if __name__ == "__main__":
    main()
