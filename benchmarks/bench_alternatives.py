"""The alternatives to the built-in PSO, per frame, against it in one run on one core.

    taskset -c 0 python benchmarks/bench_alternatives.py [--frames 40] [--budget 3400] [--repeat 5]
                                                         [--only NAME ...] [--quick] [--json PATH]

One process pinned to one core (``taskset -c 0``; the script pins itself to the first core it
may use too). Every row is ``hybridfit.fit`` of the same frames at the same budget and seed,
compiled first (a warm-up fit of two frames), then ``--repeat`` rounds, each round every row once
(alternated, so a load that changes during the run falls on all alike):

- ``pso``, ``nlopt``, ``cmaes``, ``casadi-ik``: ``stepwise`` with each as its inner optimiser
  and ``local_share = 0`` (the paper's schedule: palm, then each finger; no local stage), on
  the paper's objective ``clamped-confidence``, ``--frames`` synthetic frames (k = 3, seed 2015),
  budget ``--budget``;
- ``pycma``, ``cmaes package``: CMA-ES through a package, as callback solvers in the same
  schedule, each generation one ``task.evaluate`` (pycma's batched ask/tell, as the ``cmaes``
  plugin ran in 0.13; the ``cmaes`` package's CMA, asked one sample at a time, told the
  generation): the measurement behind ``cmaes``'s own compiled CMA-ES (rows left out when the
  package is not installed);
- ``hybrid``: the ``hybrid`` objective's fit (its default schedule) on the rendered test
  sequence of ``benchmarks/bench_depth_objective.py`` (``--hybrid-frames`` frames, proposals the
  true joints plus 8 mm noise, k = 3), the error against the rendered poses' joints.

Figures: ms/frame, the median over rounds of each row's CPU time per frame; x pso, the median
over rounds of the row's time per frame over ``pso``'s in the same round; the mean joint error
(mm) of the first round's fit against the ground truth (it is the same every round: one seed).
The table and the figures go to ``--json`` (default ``benchmarks/results/alternatives.json``).
``--quick``: a smoke run at tiny settings (4 frames, budget 600, one round).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import hybridfit  # noqa: E402
from _util import json_argument, table, table_record, write_record  # noqa: E402
from hybridfit import registry  # noqa: E402
from hybridfit.errors import HybridfitError  # noqa: E402
from hybridfit.metrics import joint_errors  # noqa: E402
from hybridfit.optimizer import Task  # noqa: E402
from hybridfit.optional import MissingLibrary  # noqa: E402
from hybridfit_plugins.optimizers.cmaes import CMAES  # noqa: E402

COLUMNS = ["plugin", "ms/frame", "x pso", "mean joint error (mm)", "what runs"]


class PycmaCMAES(CMAES):
    """CMA-ES through pycma as the ``cmaes`` plugin ran it in 0.13: a callback solver, pycma's batched
    ask/tell in the unit-scaled box with its bound transform, one ``task.evaluate`` per generation,
    IPOP restarts (``git show 7d66f84~1:plugins/optimizers/cmaes.py``)."""

    requires = {"cma": "cma"}

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        import cma

        lower, span = task.lower, np.where(task.upper > task.lower, task.upper - task.lower, 1.0)
        start, lam = (task.x0 - lower) / span, self.popsize(task.dim)
        while task.remaining > 0:
            used = task.used
            es = cma.CMAEvolutionStrategy(start, self.settings.sigma, {
                "bounds": [0.0, 1.0], "popsize": lam, "randn": lambda *shape: rng.standard_normal(shape),
                "seed": np.nan, "verbose": -9, "verb_log": 0, "verb_disp": 0, "CMA_active": True})
            while not es.stop() and task.remaining > 0:
                Z = np.asarray(es.ask())
                m = min(len(Z), task.remaining)
                losses = task.evaluate(np.clip(lower + Z[:m] * span, lower, task.upper))
                if m < len(Z):
                    return
                es.tell(list(Z), losses.tolist())
            if task.used == used:
                return
            start, lam = (task.best_x - lower) / span, round(lam * self.settings.popsize_factor)


class PackageCMAES(CMAES):
    """CMA-ES through the ``cmaes`` package (``pip install cmaes``): its ``CMA`` in the unit-scaled
    box (its own bound handling: resampling, then clipping), each generation's samples asked one at
    a time and scored in one ``task.evaluate``, restarted with a grown population when it stops."""

    requires = {"cmaes": "cmaes"}

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        from cmaes import CMA

        lower, span = task.lower, np.where(task.upper > task.lower, task.upper - task.lower, 1.0)
        start, lam = (task.x0 - lower) / span, self.popsize(task.dim)
        bounds = np.repeat([[0.0, 1.0]], task.dim, axis=0)
        while task.remaining > 0:
            es = CMA(mean=start, sigma=self.settings.sigma, bounds=bounds, population_size=lam,
                     seed=int(rng.integers(2**31)))
            while not es.should_stop() and task.remaining > 0:
                Z = np.array([es.ask() for _ in range(lam)])
                m = min(lam, task.remaining)
                losses = task.evaluate(np.clip(lower + Z[:m] * span, lower, task.upper))
                if m < lam:
                    return
                es.tell(list(zip(Z, losses)))
            start, lam = (task.best_x - lower) / span, round(lam * self.settings.popsize_factor)


@contextlib.contextmanager
def pinned():
    """This process on one core (the first it may use), as ``taskset -c 0`` would, while in the block."""
    if not hasattr(os, "sched_setaffinity"):
        yield
        return
    cores = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(cores)})
    try:
        yield
    finally:
        os.sched_setaffinity(0, cores)


#: the rows on synthetic frames: label -> (stepwise's inner optimiser, what the table says runs)
SEARCH = {
    "pso": ("pso", "the built-in PSO: numba batch steps, every frame in lockstep"),
    "nlopt": ("nlopt", "NLopt (default neldermead), its C library calling a compiled objective"),
    "cmaes": ("cmaes", "CMA-ES as numba batch steps, every frame in lockstep"),
    "casadi-ik": ("casadi-ik", "CasADi's SQP method (daqp QPs) on its symbolic kinematics, one problem per stage"),
    "pycma": (registry.reference(PycmaCMAES), "CMA-ES through pycma: batched ask/tell per frame (0.13's cmaes)"),
    "cmaes package": (registry.reference(PackageCMAES), "CMA-ES through the cmaes package: ask/tell per frame"),
}
HYBRID = "hybrid objective (whole fit)"


def synthetic_runs(frames: int, budget: int, only) -> tuple[dict, dict]:
    """{label: fit()} of the rows on synthetic frames whose plugins are installed, and {label: why
    not} of the others; each fit returns (seconds of CPU per frame, mean joint error mm)."""
    data = hybridfit.synthetic_proposals(frames, k=3, seed=2015)
    model = hybridfit.create("model", "hand26")
    runs, missing = {}, {}
    for label, (inner, _) in SEARCH.items():
        if only and label not in only:
            continue
        try:
            optimizer = hybridfit.create("optimizer", "stepwise", {"optimizer": inner, "local_share": 0.0})
            optimizer.inner  # noqa: B018 - creating it checks its library
        except (MissingLibrary, HybridfitError) as err:
            missing[label] = str(err).split(": pip install")[0]
            continue

        def fit(n=frames, optimizer=optimizer):
            start = time.process_time()
            result = hybridfit.fit(data["proposals"][:n], data["confidences"][:n], objective="clamped-confidence",
                                   optimizer=optimizer, budget=budget, seed=0)
            seconds = (time.process_time() - start) / n
            assert (result.evaluations <= budget).all()  # casadi-ik may stop short of it
            return seconds, float(joint_errors(model.forward(result.params), data["ground_truth"][:n]).mean())

        runs[label] = fit
    return runs, missing


def hybrid_run(frames: int, budget: int):
    """The ``hybrid`` objective's fit on the rendered test sequence (bench_depth_objective's), as
    fit(n) -> (seconds of CPU per frame, mean joint error mm)."""
    from hybridfit.model.render import Renderer
    from hybridfit.objective import Observation
    from hybridfit.synthetic.poses import sequence_poses

    model = hybridfit.create("model", "hand26")
    renderer = Renderer(model)
    poses = sequence_poses({"frames": frames})
    depth = renderer.render(poses)[0]
    truth = model.forward(poses)
    props = truth[:, :, None] + np.random.default_rng(1).normal(0, 8, truth.shape[:2] + (3, 3))
    conf = np.ones(props.shape[:3])
    observations = [Observation.from_depth(d, renderer.intrinsics) for d in depth]

    def fit(n=frames):
        start = time.process_time()
        result = hybridfit.fit(props[:n], conf[:n], objective="hybrid", budget=budget, observations=observations[:n])
        seconds = (time.process_time() - start) / n
        return seconds, float(joint_errors(result.joints, truth[:n]).mean())

    return fit


def measure(runs: dict, repeat: int) -> dict:
    """{label: {"ms": median ms/frame, "ratio": median x pso, "error": mm, "ms_rounds": [...]}}."""
    for fit in runs.values():
        fit(2)  # compiles what is not cached yet (numba, CasADi's functions), outside the timing
    times = {label: [] for label in runs}
    errors = {}
    for _ in range(repeat):
        for label, fit in runs.items():
            seconds, error = fit()
            times[label].append(seconds)
            errors.setdefault(label, error)
    out = {}
    for label in runs:
        ratios = [t / p for t, p in zip(times[label], times["pso"])] if "pso" in times else []
        out[label] = {"ms": 1e3 * statistics.median(times[label]), "ms_rounds": [1e3 * t for t in times[label]],
                      "ratio": statistics.median(ratios) if ratios else math.nan, "error": errors[label]}
    return out


def _figure(value: float) -> str:
    """Three significant digits, a large value whole (3,190, not 3.19e+03)."""
    return f"{value:,.0f}" if value >= 100 else f"{value:.3g}"


def rows(figures: dict, missing: dict) -> list[list]:
    """The table's rows: the measured ones, then those whose plugin is not installed."""
    what = {**{label: text for label, (_, text) in SEARCH.items()},
            HYBRID: "the hybrid objective (proposals + depth), its default schedule, on the rendered sequence"}
    out = [[label, _figure(f["ms"]), f"{_figure(f['ratio'])}x" if math.isfinite(f["ratio"]) else "",
            f"{f['error']:.2f}", what[label]] for label, f in figures.items()]
    return out + [[label, "", "", "", f"not measured: {why}"] for label, why in missing.items()]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=40, help="synthetic frames (default 40)")
    ap.add_argument("--hybrid-frames", type=int, default=40, help="frames of the rendered sequence (default 40)")
    ap.add_argument("--budget", type=int, default=3400, help="evaluations per frame (default 3400)")
    ap.add_argument("--repeat", type=int, default=5, help="rounds, each row once a round (default 5)")
    ap.add_argument("--only", nargs="+", metavar="NAME", help=f"these rows only ({', '.join(SEARCH)}, hybrid); "
                    "pso is always measured, as the reference")
    ap.add_argument("--quick", action="store_true", help="a smoke run: 4 frames (hybrid: 2), budget 600, one round")
    json_argument(ap, "alternatives")
    a = ap.parse_args(argv)
    if a.quick:
        a.frames, a.hybrid_frames, a.budget, a.repeat = 4, 2, 600, 1
    only = None if a.only is None else {*a.only, "pso"}
    with pinned():
        runs, missing = synthetic_runs(a.frames, a.budget, only)
        if only is None or "hybrid" in only:
            runs[HYBRID] = hybrid_run(a.hybrid_frames, a.budget)
        figures = measure(runs, a.repeat)
    header = COLUMNS
    print(f"{a.frames} synthetic frames (hybrid: {a.hybrid_frames} rendered), budget {a.budget}, one core, "
          f"CPU ms/frame and the ratio to pso: medians of {a.repeat} rounds")
    table_rows = rows(figures, missing)
    print(table(header, table_rows))
    write_record(a.json, {"alternatives": {**table_record(header, table_rows),
                                           "title": f"The alternatives against the built-in PSO, per frame ({a.frames} "
                                                    f"synthetic frames, budget {a.budget}, stepwise without a local "
                                                    f"stage; medians of {a.repeat} rounds)"}},
                 frames=a.frames, hybrid_frames=a.hybrid_frames, budget=a.budget, repeat=a.repeat, figures=figures,
                 missing=missing)
    return 0


if __name__ == "__main__":
    sys.exit(main())
