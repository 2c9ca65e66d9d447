"""Speed of the core on one core: kernel throughput, fitting per frame (compiled and Task
paths), their accuracy side by side, --jobs scaling and start-up.

    python benchmarks/bench_core.py [--frames 200 --seeds 20]

Prints (medians of CPU time, so other jobs on a shared machine disturb little):
1. batched forward kinematics + clamped-confidence objective (the Task path's kernel),
   hypotheses per second at batches of 64 and 1000 (21 joints, k = 3);
2. stepwise PSO per frame at budgets 1000 and 3400, with the default schedule (a final joint
   refinement, ``refine_share`` 0.25) and the paper's (none): the compiled path's numba call alone,
   ``hybridfit.fit`` end to end (problem set-up included) and the Task path
   (``Optimizer.run`` per frame);
3. the compiled against the Task path over ``--seeds`` seeds x ``--frames`` frames: mean
   joint error, and how many fits are identical; and PSO's counter-based random streams
   against numpy's generator drawn directly (hybridfit's streams before the compiled path
   computed them in its loop): mean joint error, paired over seeds;
4. ``hybridfit.fit`` with ``--jobs`` 1 and 2 (threads), wall time (without taskset);
5. start-up: a fresh process's import + first fit, compiling and from numba's cache.
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
from hybridfit.fitting import compiled, frames as fitting
from hybridfit.metrics import joint_errors
from hybridfit.problem import Problem
from hybridfit_plugins.optimizers.pso import PSO

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from _util import median_time, table  # noqa: E402


def throughput(problem: Problem, n: int) -> float:
    """Hypotheses per CPU second of problem.evaluate on batches of n."""
    rng = np.random.default_rng(0)
    X = problem.x0 + rng.normal(0, 0.05, (n, problem.x0.size))
    problem.evaluate(X)
    reps = max(1, 20_000 // n)
    return n * reps / median_time(lambda: [problem.evaluate(X) for _ in range(reps)], repeat=9, clock=time.process_time)


#: stepwise-pso's default schedule (a final joint refinement) and the paper's (none)
SCHEDULES = {"default": {}, "paper": {"refine_share": 0.0}}


class NumpyStreamPSO(PSO):
    """The ``pso`` plugin drawing straight from numpy's generator, as it did before its
    counter-based streams (uniform initial swarm, Gaussian share around the guess, r1, r2)."""

    def minimize(self, task, rng: np.random.Generator) -> None:
        s = self.settings
        n, near = self.swarm(task.budget, task.remaining)
        lower, upper = task.lower, task.upper
        span = upper - lower
        x = rng.uniform(lower, upper, size=(n, task.dim))
        if near:
            x[:near] = task.x0 + rng.normal(0.0, s.init_sigma, size=(near, task.dim)) * span
            x[0] = task.x0
        np.clip(x, lower, upper, out=x)
        v = np.zeros_like(x)
        f = task.evaluate(x)
        pbest_x, pbest_f = x.copy(), f.copy()
        g = int(np.argmin(pbest_f))
        chi = compiled.constriction(s.cognitive, s.social)
        vmax = s.max_velocity * span
        while task.remaining > 0:
            m = min(n, task.remaining)
            r = rng.random((2, m, task.dim))
            compiled.pso_step(x, v, pbest_x, pbest_x[g].copy(), r[0], r[1], chi, s.cognitive, s.social, vmax, lower,
                              upper, m)
            f[:m] = task.evaluate(x[:m])
            g = compiled.update_bests(x, f, pbest_x, pbest_f, m)


def stepwise_pso(schedule: str = "default", numpy_streams: bool = False):
    """stepwise-pso with a schedule; its PSOs draw from numpy's generator with numpy_streams."""
    optimizer = hybridfit.create("optimizer", "stepwise-pso", SCHEDULES[schedule])
    if numpy_streams:
        optimizer.__dict__["inner"] = NumpyStreamPSO(**optimizer.inner.get_params())
    return optimizer


def task_path(data, budget: int, seed: int, schedule: str = "default",
              numpy_streams: bool = False) -> tuple[np.ndarray, float]:
    """(params (F, P), median CPU seconds per frame) of Optimizer.run per frame."""
    model = hybridfit.create("model", "hand26")
    spec = fitting._Spec(model, hybridfit.create("objective", "clamped-confidence"),
                         stepwise_pso(schedule, numpy_streams), budget, seed, tuple(model.joint_names), 60.0)
    params, times = [], []
    for f in range(len(data["proposals"])):
        t = time.process_time()
        (item,) = fitting._fit_chunk(spec, [f], data["proposals"][f:f + 1], data["confidences"][f:f + 1])
        times.append(time.process_time() - t)
        params.append(item[1][0])
    return np.array(params), float(np.median(times))


def compiled_call(data, budget: int, schedule: str = "default") -> float:
    """CPU seconds per frame of the compiled path's numba call alone (set-up excluded)."""
    model = hybridfit.create("model", "hand26")
    objective = hybridfit.create("objective", "clamped-confidence")
    fitter = compiled.CompiledFitter(model, objective, hybridfit.create("optimizer", "stepwise-pso", SCHEDULES[schedule]),
                                     model.joint_names, budget, 0)
    chunk = fitter.prepare(range(len(data["proposals"])), data["proposals"], data["confidences"])
    args = (chunk.proposals, chunk.weights, chunk.x0, chunk.lower, chunk.upper, chunk.layouts, chunk.keys)
    fitter.fit(*args)
    return median_time(lambda: fitter.fit(*args), repeat=7, clock=time.process_time) / len(chunk.layouts)


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
    parser.add_argument("--seeds", type=int, default=20, help="seeds of the compiled-vs-Task accuracy comparison")
    args = parser.parse_args()
    data = hybridfit.synthetic_proposals(args.frames, k=3, seed=2015)
    model = hybridfit.create("model", "hand26")
    objective = hybridfit.create("objective", "clamped-confidence")
    problem = Problem(model, objective, data["proposals"][0], data["confidences"][0])
    hybridfit.fit(data["proposals"][:2], data["confidences"][:2])  # compile

    rows = [[f"forward kinematics + objective, batch {n}, hypotheses/s", f"{throughput(problem, n):,.0f}"]
            for n in (64, 1000)]
    small = {k: v[:40] for k, v in data.items()}
    for schedule in SCHEDULES:
        for budget in (1000, 3400):
            name = f"stepwise PSO @{budget}, {schedule} schedule"
            rows += [
                [f"{name}, compiled path, numba call, CPU ms/frame", f"{compiled_call(small, budget, schedule) * 1e3:.3f}"],
                [f"{name}, hybridfit.fit end to end, CPU ms/frame",
                 f"{fit_time(data, budget, schedule=schedule) * 1e3:.3f}"],
                [f"{name}, Task path, CPU ms/frame", f"{task_path(small, budget, 0, schedule)[1] * 1e3:.3f}"],
            ]
    errors, identical, equal, total = {"compiled": [], "task": [], "numpy": []}, 0, 0, 0
    for seed in range(args.seeds):
        fast = hybridfit.fit(data["proposals"], data["confidences"], seed=seed)
        slow, _ = task_path(data, 3400, seed)
        old, _ = task_path(data, 3400, seed, numpy_streams=True)
        for name, params in (("compiled", fast.params), ("task", slow), ("numpy", old)):
            errors[name].append(joint_errors(model.forward(params), data["ground_truth"]).mean())
        identical += int((np.abs(fast.params - slow).max(axis=1) <= 1e-9).sum())
        equal += int((fast.params == slow).all(axis=1).sum())
        total += len(slow)
    diff = np.array(errors["compiled"]) - np.array(errors["task"])
    streams = np.array(errors["compiled"]) - np.array(errors["numpy"])
    rows += [
        [f"mean joint error over {args.seeds} seeds x {args.frames} frames, compiled / Task path (mm)",
         f"{np.mean(errors['compiled']):.3f} / {np.mean(errors['task']):.3f} (paired difference "
         f"{diff.mean():+.4f} +- {diff.std():.4f})"],
        ["fits identical to 1e-9 / bit for bit (compiled vs Task path)", f"{identical} / {equal} of {total}"],
        ["the same, counter-based streams / numpy's generator (Task path) (mm)",
         f"{np.mean(errors['compiled']):.3f} / {np.mean(errors['numpy']):.3f} (paired difference "
         f"{streams.mean():+.4f} +- {streams.std(ddof=1) / np.sqrt(len(streams)):.4f} standard error, "
         f"seed-to-seed sd {np.std(errors['numpy'], ddof=1):.4f})"],
    ]
    one = fit_time(data, 3400, 1, time.perf_counter)
    two = fit_time(data, 3400, 2, time.perf_counter)
    rows.append(["hybridfit.fit --jobs 1 / 2, wall ms/frame (speed-up)", f"{one * 1e3:.3f} / {two * 1e3:.3f} ({one / two:.2f}x)"])
    first, second = startup()
    rows.append(["fresh process, import + first fit (s): compiling / from numba's cache", f"{first:.2f} / {second:.2f}"])
    print(f"## Core speed (synthetic frames, k = 3, one core unless said)\n")
    print(table(["measure", "value"], rows))


if __name__ == "__main__":
    main()
