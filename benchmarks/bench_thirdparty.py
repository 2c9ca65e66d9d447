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
time over the built-in's, the median over rounds of the ratio within a round (so a load that
changes between rounds cancels out).

``--breakdown`` first shows where a numpy objective's time goes: fits with objectives that
score nothing (all-zero losses through ``score_frames``, or through ``bind`` per frame), whose
time is the driver's, the kinematics' and the PSO's alone, against the built-in; one
refinement generation's kinematics alone, with the points written out for ``score_frames``,
and with the built-in's compiled kernel (the driver's scorers' calls); then, at each
stage's batch (hypotheses x scored points) of the default schedule, the example's bound loss
per call on points as the driver hands them (a view with the hypothesis innermost,
``hybridfit.testing.hypotheses_innermost``) and on a C-ordered copy, and its ``score_frames``
per call for all frames on the driver's arguments (the frame innermost,
``hybridfit.testing.frames_arguments``) and on C-ordered copies.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import timeit
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


class FreeBind(Objective):
    """Scores nothing, through ``bind`` per frame: a fit's time is the driver's and the kinematics'."""

    def bind(self, proposals, weights):
        return lambda points, subset: np.zeros(len(points))


class FreeFrames(FreeBind):
    """Scores nothing, through ``score_frames`` for all frames at once."""

    def score_frames(self, points, subset, proposals, weights):
        return np.zeros(points.shape[:2])


def breakdown(data, budget: int, repeat: int) -> None:
    """Print the driver's share of a numpy objective's fit and the example's cost per call."""
    from hybridfit.testing import frames_arguments, hypotheses_innermost

    built_in = dict(objective="clamped-confidence")
    for name, free in (("score_frames", FreeFrames()), ("bind", FreeBind())):
        (t_ref, _, s_ref), (t, _, s) = measure(data, budget, repeat, built_in, dict(objective=free))
        print(f"nothing scored through {name:12s} {t:6.3f} ms per frame, {paired_ratio(s, s_ref):.2f}x the "
              f"built-in's {t_ref:.3f} ms")
    scoring_breakdown(data, budget)
    all_proposals = data["proposals"]
    all_weights = hybridfit.objective.normalise_confidences(data["confidences"])
    proposals, weights = all_proposals[0], all_weights[0]
    objective = NumpyClamped()
    loss = objective.bind(proposals, weights)
    rng = np.random.default_rng(0)
    F, Q = all_proposals.shape[:2]
    for stage, n, m in (("palm", 28, 6), ("finger", 19, 3), ("refinement", 29, Q)):
        points = proposals[None, :, 0] + rng.normal(0.0, 20.0, size=(n, Q, 3))
        subset = np.sort(rng.choice(Q, m, replace=False)).astype(np.int64)
        us = [1e6 * min(timeit.repeat(lambda p=p: loss(p, subset), number=1000, repeat=5)) / 1000
              for p in (hypotheses_innermost(points), points)]
        print(f"bound loss per call, {stage:10s} ({n} x {m:2d} points): {us[0]:6.1f} us on the driver's view, "
              f"{us[1]:6.1f} us on a C-ordered copy")
        frames = all_proposals[:, None, :, 0] + rng.normal(0.0, 20.0, size=(F, n, Q, 3))
        laid_out = frames_arguments(frames, subset, all_proposals, all_weights)
        c_ordered = [np.ascontiguousarray(a) for a in laid_out]
        us = [1e6 * min(timeit.repeat(lambda a=a: objective.score_frames(*a), number=20, repeat=5)) / 20
              for a in (laid_out, c_ordered)]
        print(f"score_frames per call, {stage:10s} ({F} frames x {n} x {m:2d} points): {us[0]:7.1f} us on the "
              f"driver's layout, {us[1]:7.1f} us on C-ordered arrays")


def scoring_breakdown(data, budget: int) -> None:
    """Print one refinement generation's scoring (all parameters move, all points scored, 29
    hypotheses per frame, every frame at once) as the driver's scorers run it: the
    kinematics alone, the kinematics with the points written out for ``score_frames``
    (``evaluator.write_points``), and the built-in's kinematics with its compiled kernel
    (``evaluator.kernel_frames``)."""
    from hybridfit.fitting import driver, evaluator

    model, objective = hybridfit.create("model", "hand26"), hybridfit.create("objective", "clamped-confidence")
    fitter = driver.Driver(model, objective, hybridfit.create("optimizer", "stepwise-pso"), data["joint_names"],
                           budget, 0)
    chunk = fitter.prepare(range(len(data["proposals"])), data["proposals"], data["confidences"])
    F, P, Q, n = len(chunk.kept), model.n_params, len(fitter.names), 29
    every, points = np.arange(P), np.arange(Q)
    X = chunk.x0[:, None] + np.random.default_rng(1).normal(0.0, 0.02, size=(F, n, P))
    stage = evaluator.block_setup(*fitter.tree, *fitter.point_map, chunk.x0, every, points, points, n)
    out, losses = np.empty((3, n, Q, F)), np.empty((F, n))
    kernel = (evaluator.as_cfunc(fitter.kernel[0]), fitter.kernel[1])
    address = evaluator.callback_address(kernel[0])  # kernel[0] keeps the callback alive
    proposals, weights = np.ascontiguousarray(chunk.proposals), np.ascontiguousarray(chunk.weights)
    calls = {
        "kinematics alone": lambda: evaluator.write_points(
            *fitter.tree, *fitter.point_map, *stage, X, points[:0], out, False, True),
        "kinematics + points written for score_frames": lambda: evaluator.write_points(
            *fitter.tree, *fitter.point_map, *stage, X, points, out, False, True),
        "kinematics + compiled kernel (built-in)": lambda: evaluator.kernel_frames()(
            address, kernel[1], proposals, weights, *fitter.tree, *fitter.point_map, *stage, X, points, losses),
    }
    for name, call in calls.items():
        call()
        us = 1e6 * min(timeit.repeat(call, number=10, repeat=9)) / 10
        print(f"one refinement generation ({F} frames x {n} x {Q} points), {name:45s} {us:7.1f} us")


def measure(data, budget: int, repeat: int, *plugins: dict) -> list[tuple[float, float, np.ndarray]]:
    """For each set of plugins: (CPU ms per frame, median over ``repeat`` fits; mean joint
    error mm; each round's CPU seconds (repeat,)). The sets' fits alternate, a round of each
    after the other."""
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
    return [(1e3 * float(np.median(s)) / len(data["proposals"]), e, np.asarray(s)) for s, e in zip(seconds, errors)]


def paired_ratio(third_party: np.ndarray, built_in: np.ndarray) -> float:
    """The median over rounds of third-party time / built-in time in the same round: a load
    that changes between rounds cancels out of it."""
    return float(np.median(third_party / built_in))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--budget", type=int, default=3400)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--cpu", type=int, default=0, help="the core to run on")
    parser.add_argument("--breakdown", action="store_true", help="first show where a numpy objective's time goes")
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {args.cpu})
    data = hybridfit.synthetic_proposals(args.frames, k=3, seed=11)
    if args.breakdown:
        breakdown(data, args.budget, args.repeat)
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
        (t_ref, e_ref, s_ref), (t, e, s) = measure(data, args.budget, args.repeat, built_in, third_party)
        ratio = paired_ratio(s, s_ref)
        print(f"{name:10s} built-in {t_ref:6.3f} ms ({e_ref:.2f} mm)   third-party {t:6.3f} ms ({e:.2f} mm)   "
              f"{ratio:.2f}x")
        ratios.append(f"{name} {ratio:.1f}x")
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
