"""``hybridfit.fit``: fit a hand model to every frame's joint proposals.

Frames are independent: frame i is optimised with the random stream
``numpy.random.default_rng([seed, i])``, so results are identical for any number of
``jobs``. A frame that fails is recorded (``failed``, ``errors``) and the others go on;
an interrupt (Ctrl-C) stops the run and keeps every finished frame.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
from tqdm.auto import tqdm

from . import registry
from .io import validate_proposals
from .optimizer import Task
from .problem import Problem


@dataclass
class FitResult:
    """Per-frame fits. params (F, P); joints (F, Q, 3) mm in the input's point order
    (``joint_names``); model_joints (F, J, 3) mm; objective (F,) the minimised loss;
    evaluations (F,); failed (F,) bool with ``errors`` {frame: message}."""

    params: np.ndarray
    joints: np.ndarray
    model_joints: np.ndarray
    objective: np.ndarray
    evaluations: np.ndarray
    joint_names: tuple[str, ...]
    failed: np.ndarray
    errors: dict[int, str] = field(default_factory=dict)
    interrupted: bool = False

    def to_npz(self) -> dict[str, np.ndarray]:
        """The arrays written by ``hybridfit fit --out``."""
        frames = sorted(self.errors)
        return {
            "params": self.params,
            "joints": self.joints,
            "model_joints": self.model_joints,
            "objective": self.objective,
            "evaluations": self.evaluations,
            "joint_names": np.asarray(self.joint_names),
            "failed": self.failed,
            "error_frames": np.asarray(frames, dtype=np.int64),
            "error_messages": np.asarray([self.errors[f] for f in frames], dtype=str),
        }


@dataclass(frozen=True)
class _Spec:
    """Everything a worker needs to fit frames (picklable)."""

    model: Any
    objective: Any
    optimizer: Any
    budget: int
    seed: int
    point_names: tuple[str, ...]
    search_radius_mm: float


def _fit_one(spec: _Spec, frame: int, proposals: np.ndarray, confidences: np.ndarray):
    problem = Problem(spec.model, spec.objective, proposals, confidences, spec.point_names, spec.search_radius_mm)
    result = spec.optimizer.run(problem, spec.budget, np.random.default_rng([spec.seed, frame]))
    points = problem.points(result.params[None])[0]
    return result.params, points, spec.model.forward(result.params), result.loss, result.evaluations


def _fit_chunk(spec: _Spec, frames: Sequence[int], proposals, confidences):
    out = []
    for i, f in enumerate(frames):
        try:
            out.append((f, _fit_one(spec, f, proposals[i], confidences[i]), None))
        except Exception as err:  # recorded per frame; the other frames go on
            out.append((f, None, f"{type(err).__name__}: {err}"))
    return out


def fit(
    proposals: np.ndarray,
    confidences: np.ndarray,
    *,
    model: Any = "hand26",
    objective: Any = "clamped-confidence",
    optimizer: Any = "stepwise-pso",
    budget: int = 3400,
    seed: int = 0,
    joint_names: Sequence[str] | None = None,
    model_config: Mapping[str, Any] | None = None,
    objective_config: Mapping[str, Any] | None = None,
    optimizer_config: Mapping[str, Any] | None = None,
    search_radius_mm: float = 60.0,
    jobs: int = 1,
    progress: bool = False,
) -> FitResult:
    """Fit the model to each frame's proposals.

    proposals: (F, J, K, 3) mm; confidences: (F, J, K) >= 0 (normalised per joint here);
    joint_names: the J proposal points as model joint or derived-point names (default: the
    model's joints in order). Plugins are registered names (with ``*_config`` settings) or
    plugin instances. budget: objective evaluations per frame, honoured exactly.
    """
    model = registry.create("model", model, model_config)
    objective = registry.create("objective", objective, objective_config)
    optimizer = registry.create("optimizer", optimizer, optimizer_config)
    names = tuple(joint_names) if joint_names is not None else tuple(model.joint_names)
    proposals, confidences = validate_proposals(proposals, confidences, names)
    F = len(proposals)
    spec = _Spec(model, objective, optimizer, int(budget), int(seed), names, float(search_radius_mm))
    if F:  # user errors that would fail every frame are raised at once
        problem = Problem(model, objective, proposals[0], confidences[0], names, search_radius_mm)
        optimizer.check_budget(Task(problem, budget))

    P, Q, J = model.n_params, len(names), model.n_joints
    result = FitResult(
        params=np.full((F, P), np.nan),
        joints=np.full((F, Q, 3), np.nan),
        model_joints=np.full((F, J, 3), np.nan),
        objective=np.full(F, np.nan),
        evaluations=np.zeros(F, dtype=np.int64),
        joint_names=names,
        failed=np.ones(F, dtype=bool),
    )
    done = np.zeros(F, dtype=bool)

    def store(items):
        for f, values, error in items:
            done[f] = True
            if error is not None:
                result.errors[f] = error
                continue
            (result.params[f], result.joints[f], result.model_joints[f], result.objective[f],
             result.evaluations[f]) = values
            result.failed[f] = False

    bar = tqdm(total=F, disable=not progress, unit="frame", desc="fit")
    try:
        if jobs <= 1 or F <= 1:
            for f in range(F):
                store(_fit_chunk(spec, [f], proposals[f : f + 1], confidences[f : f + 1]))
                bar.update(1)
        else:
            chunks = np.array_split(np.arange(F), min(F, jobs * 8))
            ctx = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn")
            with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
                futures = [pool.submit(_fit_chunk, spec, list(c), proposals[c], confidences[c]) for c in chunks if len(c)]
                try:
                    for fut in as_completed(futures):
                        items = fut.result()
                        store(items)
                        bar.update(len(items))
                except KeyboardInterrupt:
                    for fut in futures:
                        fut.cancel()
                    raise
    except KeyboardInterrupt:
        result.interrupted = True
        for f in np.flatnonzero(~done):
            result.errors[int(f)] = "interrupted"
    finally:
        bar.close()
    return result
