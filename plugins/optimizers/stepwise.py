"""``stepwise`` and ``stepwise-pso``: the paper's stepwise optimisation as a wrapper.

The model's stages are optimised in order (for hand26: the palm's 7 global parameters on
the palm joints, then each finger's 4 angles on that finger's joints), each with its own
share of the budget, each starting from the result of the stages before. With
``schedule = "joint"`` the same code runs one stage with all parameters on all points, so
the paper's ablation (91x91 jointly vs 64x64 + 5 x 29x29 stepwise) is one setting away.

Budget split: ``root_share`` of the budget goes to the first (global) stage and the rest
is split equally between the other stages; ``stage_weights`` overrides this with one
relative weight per stage (the paper's ablation: [4096, 841, 841, 841, 841, 841]).
Stage budgets are rounded by largest remainder, so they add up to the budget exactly.
The paper leaves the split of its default 3400 open; the default root share, 0.3, was chosen
on synthetic frames with ``studies/stepwise_vs_joint_synthetic.toml`` (figures: the docs' results page).
``refine_share`` (an extension; 0 for both by default) keeps a share of the budget for a
joint refinement of all parameters starting from the stepwise result, run with the inner
optimiser's settings overridden by ``refine_config``. ``local_share`` (an extension; 0 for
``stepwise``, the paper's schedule) keeps a share for a last, local stage of all parameters:
``local_optimizer`` (``levenberg-marquardt``, gradient-based, through the kinematic tree and
the objective's per-point loss) on ``local_objective`` (None: the objective in force). An
objective without a per-point loss (one that only binds) gets a gradient-free local stage
instead: the inner optimiser with ``refine_config`` (a swarm started near the fit). Every
stage's evaluations count in the budget.
"""

from __future__ import annotations

from functools import cached_property
from typing import Any, Literal

import numpy as np
from pydantic import Field, field_validator

from hybridfit import registry
from hybridfit.errors import HybridfitError, UnknownPluginError
from hybridfit.objective import point_loss_of
from hybridfit.optimizer import Optimizer, StagePlan, Task
from hybridfit.plugin import Settings
from hybridfit.stages import MIN_ROOT_LEVER_MM, MIN_ROOT_POINTS, guide_points, structure_of


class StepwiseSettings(Settings):
    optimizer: str = Field("pso", description="the optimiser run on each stage (a registered name)")
    optimizer_config: dict[str, Any] = Field(default_factory=dict, description="its settings")
    schedule: Literal["stepwise", "joint"] = Field("stepwise", description="stage by stage, or all parameters at once")
    root_share: float = Field(0.3, gt=0, lt=1, description="share of the budget for the global-pose stage")
    stage_weights: list[float] | None = Field(None, description="relative budget per stage (overrides root_share)")
    refine_share: float = Field(0.0, ge=0, lt=1, description="share of the budget for a final joint refinement "
                                "of all parameters (0 = the paper)")
    refine_config: dict[str, Any] = Field(default_factory=dict, description="the inner optimiser's settings "
                                          "overridden for the refinement stage and a gradient-free local stage")
    local_share: float = Field(0.0, ge=0, lt=1, description="share of the budget for a last, local stage of all "
                               "parameters (0 = the paper)")
    local_optimizer: str = Field("levenberg-marquardt", description="the local stage's optimiser (a registered name), "
                                 "for objectives with a per-point loss; the others get a gradient-free local stage")
    local_config: dict[str, Any] = Field(default_factory=dict, description="its settings")
    local_objective: str | None = Field(None, description="the objective the local stage minimises (a registered "
                                        "name); None: the objective in force")
    local_objective_config: dict[str, Any] = Field(default_factory=dict, description="its settings")
    min_root_points: int = Field(MIN_ROOT_POINTS, ge=0, description="with fewer observed points of its own, the root "
                                 "stage is also scored on guide points")
    min_root_lever_mm: float = Field(MIN_ROOT_LEVER_MM, ge=0, description="likewise below this rotation lever (mm) of "
                                     "its own observed points (nearly collinear)")

    @field_validator("optimizer", "local_optimizer")
    @classmethod
    def _registered(cls, name: str) -> str:
        return _registered("optimizer", name)

    @field_validator("local_objective")
    @classmethod
    def _registered_objective(cls, name: str | None) -> str | None:
        return None if name is None else _registered("objective", name)


def _registered(kind: str, name: str) -> str:
    if name not in registry.names(kind):
        try:
            registry.get(kind, name)
        except UnknownPluginError as err:  # names the registered ones and the closest match
            raise ValueError(str(err)) from None
    return name


def split_budget(budget: int, weights) -> list[int]:
    """Integer budgets proportional to weights that add up to ``budget`` exactly."""
    w = np.asarray(weights, float)
    ideal = budget * w / w.sum()
    out = np.floor(ideal).astype(int)
    for i in np.argsort(-(ideal - out), kind="stable")[: budget - out.sum()]:
        out[i] += 1
    return [int(b) for b in out]


def members(indices: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: which of 0 .. n - 1 are among the indices (index sets as masks: intersections
    and unions in index order, as ``np.intersect1d`` and ``np.union1d`` give them)."""
    mask = np.zeros(n, dtype=bool)
    mask[indices] = True
    return mask


class Stepwise(Optimizer):
    """Runs any registered optimiser stage by stage (palm first, then fingers) or jointly.

    The schedule adapts to the frame's points (``plan``): stages without free parameters or
    without any point that has proposals are skipped (their budget goes to the others), and
    when the root stage's own observed points cannot determine the global rotation (fewer than
    4, or collinear: ``problem.rotation_lever_mm`` below ``min_root_lever_mm``), the root stage is also
    scored on guide points: each later stage's observed points nearest to the root, with the
    fingers at their starting articulation. Guide points stay owned by their own stage.
    """

    Settings = StepwiseSettings

    @cached_property
    def inner(self) -> Optimizer:
        """The configured per-stage optimiser."""
        s = self.settings
        if s.optimizer in ("stepwise", self.name):
            raise HybridfitError(f"{self.name}: the inner optimizer cannot be a stepwise optimizer itself")
        return registry.create("optimizer", s.optimizer, s.optimizer_config)

    def _stages(self, task: Task):
        """The stages restricted to the task's parameters and observed points (those with
        proposals), with budget weights: a list of (name, parameters, points, owned), and the weights."""
        if self.settings.schedule == "joint":
            return [("joint", task.parameters, task.points, task.points)], [1.0]
        problem = task.problem
        observed = problem.weights.sum(axis=-1) > 0
        stages = problem.stage_points()
        w = self.settings.stage_weights
        if w is None:
            rest = (1.0 - self.settings.root_share) / (len(stages) - 1)
            w = [self.settings.root_share] + [rest] * (len(stages) - 1)
        elif len(w) != len(stages) or min(w) <= 0:
            raise HybridfitError(f"{self.name}: stage_weights needs {len(stages)} positive weights "
                                 f"({', '.join(s[0] for s in stages)}), got {w}")
        P, Q = problem.model.n_params, len(observed)
        free, scored = members(task.parameters, P), members(task.points, Q) & observed
        kept, weights = [], []
        for (name, params, points), weight in zip(stages, w):
            params = np.flatnonzero(members(params, P) & free)
            points = np.flatnonzero(members(points, Q) & scored)
            if len(params) and len(points):
                kept.append([name, params, points, points])
                weights.append(weight)
        if not kept:
            return [("joint", task.parameters, task.points, task.points)], [1.0]
        # points no kept stage scores only add a constant: the first stage owns them, so that
        # the stage losses still add up to the task's loss
        left = members(task.points, Q) & ~members(np.concatenate([k[3] for k in kept]), Q)
        first = kept[0]
        first[2] = first[3] = np.flatnonzero(members(first[3], Q) | left)
        if stages[0][0] == first[0] and len(kept) > 1:
            guides = guide_points(problem, first[3], [k[3] for k in kept[1:]], self.settings.min_root_points,
                                  self.settings.min_root_lever_mm)
            first[2] = np.flatnonzero(members(first[3], Q) | members(guides, Q))
        return [tuple(k) for k in kept], weights

    def _shares(self) -> tuple[float, float]:
        """The budget shares of the refinement and the local stage (none for a joint schedule)."""
        s = self.settings
        return (s.refine_share, s.local_share) if s.schedule == "stepwise" else (0.0, 0.0)

    def plan(self, task: Task) -> list[StagePlan]:
        """The frame's schedule: stages with exact budgets adding up to ``task.budget``. The local
        stage's budget is whole rows of a derivative-step optimiser (``dim + 1`` evaluations each;
        the remainder goes to the search stages), and there is no local stage where its share is
        below its optimiser's ``min_budget`` (it goes to the search stages too)."""
        stages, w = self._stages(task)
        refine_share, local_share = self._shares()
        refine, local = round(refine_share * task.budget), round(local_share * task.budget)
        optimizer, objective = self._local(task) if local else (None, None)
        if local and "derivative_steps" in type(optimizer).offers:
            local -= local % (task.dim + 1)
        if local and local < optimizer.min_budget(task):
            local = 0
        plan = [StagePlan(name, params, points, owned, budget, self.inner)
                for (name, params, points, owned), budget in zip(stages, split_budget(task.budget - refine - local, w))]
        if refine:
            plan.append(StagePlan("refine", task.parameters, task.points, task.points, refine, self.refiner))
        if local:
            plan.append(StagePlan("local", task.parameters, task.points, task.points, local, optimizer, objective))
        return plan

    def _local(self, task: Task):
        """(optimizer, objective) of the local stage: ``local_optimizer`` where the stage's
        objective has a per-point loss on a model with a kinematic tree, or observes depth with
        ``observed_derivatives``, else the gradient-free
        refiner; the objective ``local_objective``, else the objective in force's own
        ``local_objective`` form (a pair), else None (the objective in force)."""
        s = self.settings
        objective = self.local_objective if s.local_objective is not None else self._local_form(task.problem.objective)
        scored = task.problem.objective if objective is None else objective
        problem = task.problem
        tree = structure_of(problem.model, problem.point_names).tree() if callable(
            getattr(problem.model, "kinematic_tree", None)) else None
        gradient = (point_loss_of(scored) is not None and tree is not None and not scored.observes_depth) or (
            scored.observes_depth and getattr(scored, "observed_derivatives", False))
        return (self.local_optimizer if gradient else self.refiner), objective

    def min_budget(self, task: Task) -> int:
        inner = self.inner
        stages, w = self._stages(task)
        w = np.asarray(w) / np.sum(w)
        refine_share, local_share = self._shares()
        share = 1.0 - refine_share - local_share
        need = [inner.min_budget(Task(task.problem, task.budget, p, q, task.base, n, o)) / (s * share)
                for (n, p, q, o), s in zip(stages, w)]
        if refine_share:
            need.append(inner.min_budget(task) / refine_share)
        return int(np.ceil(max(need)))  # a local stage too small for its optimiser is left out

    @cached_property
    def refiner(self) -> Optimizer:
        """The inner optimiser with ``refine_config`` applied, for the refinement stage."""
        return self.inner.with_params(**self.settings.refine_config) if self.settings.refine_config else self.inner

    def _local_form(self, objective):
        """The objective's ``local_objective`` form where it offers one (a pair), else None; one
        instance per objective (the driver scores each objective instance with its own scorer)."""
        if "local_objective" not in getattr(type(objective), "offers", frozenset()):
            return None
        forms = self.__dict__.setdefault("_local_forms", {})
        if forms.get(id(objective), (None,))[0] is not objective:
            forms[id(objective)] = (objective, objective.local_objective())
        return forms[id(objective)][1]

    @cached_property
    def local_optimizer(self) -> Optimizer:
        """The configured local optimiser."""
        return registry.create("optimizer", self.settings.local_optimizer, self.settings.local_config)

    @cached_property
    def local_objective(self):
        """The configured objective of the local stage (when ``local_objective`` names one)."""
        return registry.create("objective", self.settings.local_objective, self.settings.local_objective_config)


class StepwisePSOSettings(StepwiseSettings):
    optimizer: Literal["pso"] = Field("pso", description="always PSO")
    refine_config: dict[str, Any] = Field(
        default_factory=lambda: {"init_share": 1.0, "init_sigma": 0.02},
        description="PSO settings of the refinement and a gradient-free local stage: the whole swarm starts near the fit")
    local_share: float = Field(0.2, ge=0, lt=1, description="share of the budget for a last, local stage of all "
                               "parameters (0 = the paper; 0.2 chosen on tuning data)")


class StepwisePSO(Stepwise):
    """The paper's optimiser, PSO stage by stage, palm first, then each finger; then a local step."""

    Settings = StepwisePSOSettings
