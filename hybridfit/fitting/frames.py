"""``hybridfit.fit``: fit a hand model to every frame's joint proposals.

Frames are independent and every frame runs through the one driver (:mod:`.driver`): stage
s of frame i draws from the key ``stage_key(seed, i, s)`` (:mod:`hybridfit.keys`), so results
are identical for any number of ``jobs`` and any chunking (lockstep schedules on threads,
callback solvers and depth objectives frame by frame, in worker processes with jobs > 1). A frame whose input cannot be fitted (a ``HybridfitError``: all confidences 0,
say) is recorded (``failed``, ``errors``) and the others go on; options and errors that would
fail every frame (a bad seed, a budget too small, an unknown point name) are raised before
any work; a plugin's bug (``BudgetExceeded``, a wrong shape) raises ``PluginError`` naming
the plugins. An interrupt (Ctrl-C) stops the run and keeps every finished frame.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import warnings
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np
from tqdm.auto import tqdm

from .. import registry, workers
from . import driver, stops
from ..errors import HybridfitError, PluginError
from ..io import validate_proposals
from ..keys import frame_indices
from ..metrics import inliers
from ..model.base import ANGLES
from ..task import Task
from ..problem import Problem
from ..stages import structure_of

if TYPE_CHECKING:
    from ..model.base import HandModel
    from ..names import ModelName, ObjectiveName, OptimizerName
    from ..objective import Objective
    from ..optimizer import Optimizer


#: frames per chunk of the driver (progress and Ctrl-C granularity; with jobs > 1, jobs
#: chunks run at once while the next is prepared)
CHUNK = 256
#: frames per chunk of a lockstep schedule scored in Python (a depth objective: each frame's depth is
#: held while its chunk runs)
OBSERVED_CHUNK = 16

#: seconds between checks for a stop signal while worker processes fit (the process-pool path)
STOP_POLL_S = 0.25

#: the inlier distance of objectives without a ``d_max_mm`` setting
INLIER_DISTANCE_MM = 40.0


@dataclass
class FitResult:
    """Per-frame fits. params (F, P); joints (F, Q, 3) mm in the input's point order
    (``joint_names``); model_joints (F, J, 3) mm; objective (F,) the minimised loss;
    evaluations (F,); failed (F,) bool with ``errors`` {frame: message}; inliers (F,) the
    number of points within ``inlier_distance_mm`` of one of their proposals (the
    objective's ``d_max_mm`` when it has one, else 40 mm; 0 for failed frames). ``model``
    (the plugin name; ``module:qualname`` for an unregistered class) and ``model_settings``
    (its settings as JSON) rebuild the hand (:meth:`hand`): ``model_joints`` are its forward
    kinematics of ``params``, one rigid hand in every frame."""

    params: np.ndarray
    joints: np.ndarray
    model_joints: np.ndarray
    objective: np.ndarray
    evaluations: np.ndarray
    joint_names: tuple[str, ...]
    failed: np.ndarray
    errors: dict[int, str] = field(default_factory=dict)
    interrupted: bool = False
    inliers: np.ndarray | None = None  # (F,) points within inlier_distance_mm of one of their proposals
    inlier_distance_mm: float = INLIER_DISTANCE_MM
    parameter_names: tuple[str, ...] = ()  # (P,) the model's names of the params' columns
    model: str = ""  # the model plugin's name
    model_settings: str = "{}"  # its settings, JSON
    #: the schedules that ran, JSON: [{"frames": n, "stages": [{name, kind, optimizer, objective,
    #: budget, parameters, points, owned}, ...]}, ...], one per set of observed points
    schedule: str = "[]"

    def hand(self):
        """The model that fitted these frames, rebuilt from ``model`` and ``model_settings``."""
        if not self.model:
            raise HybridfitError("this fit does not name its model (written before hybridfit 0.10.0): fit it again")
        return registry.create("model", self.model, json.loads(self.model_settings))

    def angles_deg(self) -> tuple[tuple[str, ...], np.ndarray]:
        """The joint angles: names (A,) and values (F, A) in degrees (NaN for failed frames),
        the model's parameters after the 7 of the global pose. See ``hybridfit.fitting.angles``
        for the global pose and a CSV table."""
        if len(self.parameter_names) != self.params.shape[1]:
            raise HybridfitError(f"this fit names {len(self.parameter_names)} of its {self.params.shape[1]} "
                                 "parameters: which are joint angles is unknown")
        return tuple(self.parameter_names[ANGLES]), np.degrees(self.params[:, ANGLES])

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
            "parameter_names": np.asarray(self.parameter_names, dtype=str),
            "model": np.asarray(self.model),
            "model_settings": np.asarray(self.model_settings),
            "schedule": np.asarray(self.schedule),
            "failed": self.failed,
            "error_frames": np.asarray(frames, dtype=np.int64),
            "error_messages": np.asarray([self.errors[f] for f in frames], dtype=str),
            **({} if self.inliers is None else {"inliers": self.inliers,
                                                 "inlier_distance_mm": np.asarray(self.inlier_distance_mm)}),
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
    indices: Any = None  # (F,) the frames' indices in their data set, which key their streams


def _fit_chunk(spec: _Spec, frames: Sequence[int], proposals, confidences, observations=None):
    """A worker's chunk: the same driver, in another process (:meth:`driver.Driver.fit_chunk`)."""
    fitter = driver.Driver(spec.model, spec.objective, spec.optimizer, spec.point_names, spec.budget, spec.seed,
                           spec.search_radius_mm, spec.indices)
    return fitter.fit_chunk(list(frames), proposals, confidences, observations=observations)


def _name(plugin) -> str:
    return getattr(plugin, "name", None) or type(plugin).__name__


def _first_problem(model, objective, proposals, confidences, names, search_radius_mm,
                   observations=None) -> Problem | None:
    """The problem of the first frame that can be built (None if none can): frames that
    cannot are recorded per frame later, they do not abort the run."""
    for f in range(len(proposals)):
        try:
            return Problem(model, objective, proposals[f], confidences[f], names, search_radius_mm,
                           None if observations is None else observations[f])
        except HybridfitError:
            continue
    return None


def check_fit_options(budget: int, seed: int, search_radius_mm: float, jobs: int) -> None:
    """Raise a HybridfitError naming the first invalid option (before any work)."""
    from ..keys import MAX_BUDGET, MAX_SEED

    for name, value, ok in (("budget", budget, int(budget) == budget and 1 <= budget <= MAX_BUDGET),
                            ("seed", seed, int(seed) == seed and 0 <= seed <= MAX_SEED),
                            ("search_radius_mm", search_radius_mm, np.isfinite(search_radius_mm) and search_radius_mm > 0),
                            ("jobs", jobs, int(jobs) == jobs and jobs >= 1)):
        if not ok:
            what = {"budget": f"an integer from 1 to {MAX_BUDGET:,}", "seed": "an integer from 0 to 2**64 - 1"}
            raise HybridfitError(f"{name} must be {what.get(name, 'positive')}, got {value!r}")


def check_scale(model, proposals: np.ndarray, confidences: np.ndarray, names: Sequence[str]) -> None:
    """Warn when the proposals' spread (median distance of the top proposals from their
    centre, frames with proposals only) is more than 8x off the model's: proposals in
    metres or centimetres, say, not millimetres."""
    spread = proposal_spread(proposals, confidences)
    if np.isnan(spread):  # no frame has proposals
        return
    hand = structure_of(model, names).spread_mm
    if not hand / 8 <= spread <= hand * 8:
        warnings.warn(f"the proposals spread over {spread:.3g} (median distance from their centre), the model's "
                      f"{len(names)} points over {hand:.3g} mm: are the proposals in millimetres?", stacklevel=3)


def proposal_spread(proposals: np.ndarray, confidences: np.ndarray) -> float:
    """The median over frames with proposals (a positive confidence) and their points of the
    distance of each point's most confident proposal from the frame's centre (the median of
    those proposals, per coordinate); proposals (F, Q, K, 3) mm, confidences (F, Q, K). NaN
    when no frame has proposals."""
    used = (confidences > 0).any(axis=(1, 2))
    if not used.any():
        return float("nan")
    best = np.argmax(confidences[used], axis=-1)[..., None, None]
    top = np.take_along_axis(proposals[used], best, axis=2)[:, :, 0]  # (F', Q, 3)
    return float(np.median(np.linalg.norm(top - np.median(top, axis=1, keepdims=True), axis=-1)))


def fit(
    proposals: np.ndarray,
    confidences: np.ndarray,
    *,
    model: ModelName | str | HandModel = "hand26",
    objective: ObjectiveName | str | Objective = "clamped-then-soft-l1",
    optimizer: OptimizerName | str | Optimizer = "stepwise-pso",
    budget: int = 3400,
    seed: int = 0,
    joint_names: Sequence[str] | None = None,
    model_config: Mapping[str, Any] | None = None,
    objective_config: Mapping[str, Any] | None = None,
    optimizer_config: Mapping[str, Any] | None = None,
    search_radius_mm: float = 60.0,
    jobs: int = 1,
    progress: bool = False,
    observations: Sequence[Any] | None = None,
    frames: Sequence[int] | None = None,
    scheduler: str | None = None,
) -> FitResult:
    """Fit the model to each frame's proposals.

    proposals: (F, J, K, 3) mm; confidences: (F, J, K) >= 0 (normalised per joint here);
    joint_names: the J proposal points as model joint or derived-point names (default: the
    model's joints in order). Plugins are registered names (with ``*_config`` settings) or
    plugin instances; any registered name works, the built-in ones are listed by the types
    :data:`hybridfit.names.ModelName`, ``ObjectiveName`` and ``OptimizerName`` (``hybridfit
    plugins`` lists every installed one). budget: objective evaluations per frame, honoured exactly.
    observations: per frame a ``hybridfit.objective.Observation`` (the depth), needed by
    objectives that ``observes_depth`` (``rendered-depth``, ``hybrid``). frames: each frame's
    index in its data set (default 0 .. F - 1), which keys its random streams
    (:mod:`hybridfit.keys`): a frame's fit does not depend on which of the data set's frames
    are fitted with it. scheduler: a dask.distributed scheduler's address (``tcp://HOST:PORT``;
    the ``dask`` extra): the frames are fitted there in chunks, with the same result bit for
    bit as in this process; a chunk whose worker is lost is run again on another, and each
    finished chunk is kept as it arrives (an interrupted or failed run keeps them).

    The fit is its schedule: the optimiser's stages (``stepwise-pso``: palm, fingers, then a
    local gradient step), each minimising the objective in force unless the schedule names
    another, every evaluation counted in ``budget``. ``result.schedule`` holds the stages that ran.
    """
    check_fit_options(budget, seed, search_radius_mm, jobs)
    model = registry.create("model", model, model_config)
    objective = registry.create("objective", objective, objective_config)
    optimizer = registry.create("optimizer", optimizer, optimizer_config)
    names = tuple(str(n) for n in joint_names) if joint_names is not None else tuple(model.joint_names)
    proposals, confidences = validate_proposals(proposals, confidences, names)
    if names != tuple(model.joint_names):
        model.point_matrix(names)  # an unknown point name fails every frame: raised at once
    F = len(proposals)
    if getattr(objective, "observes_depth", False) and observations is None:
        raise HybridfitError(f"objective {objective.name or type(objective).__name__} compares hypotheses with the "
                             f"depth image: give the frames' depth (observations)")
    if observations is not None and len(observations) != F:
        raise HybridfitError(f"{len(observations)} observations for {F} frames of proposals")
    indices = frame_indices(frames, F)
    spec = _Spec(model, objective, optimizer, int(budget), int(seed), names, float(search_radius_mm), indices)
    problem = _first_problem(model, objective, proposals, confidences, names, search_radius_mm, observations)
    if problem is not None:  # a budget too small fails every frame: raised at once
        optimizer.check_budget(Task(problem, budget))
        check_scale(model, proposals, confidences, names)

    P, Q, J = model.n_params, len(names), model.n_joints
    result = FitResult(
        params=np.full((F, P), np.nan),
        joints=np.full((F, Q, 3), np.nan),
        model_joints=np.full((F, J, 3), np.nan),
        objective=np.full(F, np.nan),
        evaluations=np.zeros(F, dtype=np.int64),
        joint_names=names,
        failed=np.ones(F, dtype=bool),
        parameter_names=tuple(model.parameter_names),
        **model_label(model),
    )
    done = np.zeros(F, dtype=bool)

    def store(fitted: driver.Fitted):
        rows = np.asarray(fitted.fitted, dtype=np.int64)
        (result.params[rows], result.joints[rows], result.model_joints[rows], result.objective[rows],
         result.evaluations[rows]) = fitted.params, fitted.points, fitted.joints, fitted.loss, fitted.evaluations
        result.failed[rows] = False
        result.errors.update(fitted.errors)
        done[fitted.frames] = True

    # schedules of batch or derivative steps run chunks of frames in lockstep (on threads with jobs > 1
    # where the scoring is compiled: no depth, a sum over points); callback solvers frame by frame; with
    # jobs > 1 the others in worker processes
    fitter = driver.Driver(model, objective, optimizer, names, budget, seed, search_radius_mm, indices)
    # the first frame's plan, made once: the driver keeps it for the frames with its observed points
    lockstep = problem is not None and fitter.layout(problem).lockstep
    threads = lockstep and observations is None and not fitter.observed and fitter.additive
    bar = tqdm(total=F, disable=not progress, unit="frame", desc="fit")
    try:
        with stops.deferred():  # a stop signal is raised between chunks or frames, never inside compiled code
            if scheduler is not None:
                _fit_on_cluster(scheduler, spec, F, proposals, confidences, observations, store, bar)
            elif threads or jobs <= 1 or F <= 1:
                size = (CHUNK if threads else OBSERVED_CHUNK) if lockstep else 1
                size = min(size, max(1, -(-F // jobs)))  # jobs > 1: >= jobs chunks
                chunks = [[int(f) for f in c] for c in np.array_split(np.arange(F), max(1, -(-F // size)))]
                for fitted in fitter.fit_chunks(chunks, proposals, confidences, jobs if threads else 1,
                                               observations):
                    store(fitted)
                    bar.update(len(fitted))
                    stops.check()
            else:
                chunks = np.array_split(np.arange(F), min(F, jobs * 8))
                ctx = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn")
                with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=workers.start,
                                         initargs=(os.getpid(), stops.ignored)) as pool:  # workers leave with us
                    futures = [pool.submit(_fit_chunk, spec, list(c), proposals[c], confidences[c],
                                           None if observations is None else [observations[i] for i in c])
                               for c in chunks if len(c)]
                    try:
                        pending = set(futures)
                        while pending:  # wakes every STOP_POLL_S: a stop signal is acted on at once
                            finished, pending = wait(pending, timeout=STOP_POLL_S, return_when=FIRST_COMPLETED)
                            for fut in finished:
                                fitted = fut.result()
                                store(fitted)
                                bar.update(len(fitted))
                            stops.check()
                    except KeyboardInterrupt:  # the chunks still running are lost: stop their workers now
                        for worker in list((getattr(pool, "_processes", None) or {}).values()):
                            worker.kill()  # they ignore stop signals; before shutdown, which forgets them
                        pool.shutdown(wait=False, cancel_futures=True)
                        raise
    except KeyboardInterrupt:
        result.interrupted = True
        for f in np.flatnonzero(~done):
            result.errors[int(f)] = "interrupted"
    except PluginError as err:  # a bug: it propagates, carrying the frames finished before it
        for f in np.flatnonzero(~done):
            result.errors[int(f)] = "not fitted: a plugin error stopped the run"
        err.result = _with_inliers(result, objective, proposals, confidences)
        raise
    finally:
        bar.close()
    result.schedule = json.dumps(schedules(fitter, model, objective, proposals, confidences, names,
                                           search_radius_mm, ~result.failed, observations))
    return _with_inliers(result, objective, proposals, confidences)


def _fit_on_cluster(address: str, spec: _Spec, F: int, proposals, confidences, observations, store, bar) -> None:
    """Fit the F frames on the dask scheduler at ``address`` in chunks of at most ``CHUNK``
    frames (at least 4 per worker), ``store``-ing each as it arrives; a stop signal cancels
    the chunks still running."""
    from .. import cluster

    client = cluster.connect(address)
    distributed = cluster.distributed()
    try:
        workers_n = max(1, len(client.scheduler_info().get("workers", {})))
        chunks = [c for c in np.array_split(np.arange(F), max(4 * workers_n, -(-F // CHUNK))) if len(c)]
        futures = [client.submit(_fit_chunk, spec, [int(f) for f in c], proposals[c], confidences[c],
                                 None if observations is None else [observations[i] for i in c],
                                 pure=False, retries=cluster.RETRIES) for c in chunks]
        pending = set(futures)
        try:
            while pending:  # wakes every STOP_POLL_S: a stop signal is acted on at once
                try:
                    finished = distributed.wait(pending, timeout=STOP_POLL_S, return_when="FIRST_COMPLETED").done
                except TimeoutError:  # none finished yet
                    finished = set()
                for fut in finished:
                    fitted = fut.result()  # a plugin's error is raised here, as in this process
                    store(fitted)
                    bar.update(len(fitted))
                pending -= finished
                stops.check()
        finally:
            client.cancel(list(pending))
    finally:
        client.close()


def schedules(fitter, model, objective, proposals, confidences, names, search_radius_mm, fitted,
              observations=None) -> list[dict]:
    """The schedules the fitted frames (``fitted`` (F,) bool) ran, one per set of observed points:
    [{"frames": n, "stages": [...]}] (:meth:`driver.StageRun.describe`)."""
    observed = confidences.sum(axis=-1) > 0
    out: dict[bytes, list] = {}
    for f in np.flatnonzero(fitted):
        key = observed[f].tobytes()
        if key not in out:
            lay = fitter._layouts.get(key) or fitter.layout(Problem(
                model, objective, proposals[f], confidences[f], names, search_radius_mm,
                None if observations is None else observations[f]))
            out[key] = [0, [st.describe(model.parameter_names, names, objective) for st in lay.stages]]
        out[key][0] += 1
    return [{"frames": n, "stages": stages} for n, stages in out.values()]


def model_label(model) -> dict[str, str]:
    """``model`` and ``model_settings`` of a FitResult fitted with ``model`` (a plugin instance):
    its registered name or, for a class without an entry point, ``module:qualname``
    (:func:`hybridfit.registry.reference`), which rebuilds it while its module is imported."""
    name = registry.name_of(type(model)) or registry.reference(type(model))
    return {"model": name, "model_settings": json.dumps(model.get_params(), sort_keys=True)}


def _with_inliers(result: FitResult, objective, proposals, confidences) -> FitResult:
    """The result with each frame's inlier count at the objective's d_max (or 40 mm)."""
    result.inlier_distance_mm = float(objective.get_params().get("d_max_mm", INLIER_DISTANCE_MM))
    result.inliers = inliers(result.joints, proposals, confidences, result.inlier_distance_mm)
    return result
