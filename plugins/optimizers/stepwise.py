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
The paper's ablation gives the palm 4096 of 8301 evaluations (0.49) but leaves the split of
its default 3400 open. Measured with ``benchmarks/bench_stepwise.py`` (200 synthetic frames,
budget 3400), root shares 0.3, 0.5 and 0.7 are equally good (mean joint error 10.95, 11.00
and 10.96 mm; success rate at 40 mm 0.87, 0.86, 0.87): the default, 0.3, leaves the most
budget to the fingers.
``refine_share`` (an extension, 0 by default as in the paper) keeps a share of the
budget for a final joint refinement of all parameters starting from the stepwise result;
``benchmarks/bench_stepwise.py`` measures the alternatives.
"""

from __future__ import annotations

from functools import cached_property
from typing import Any, Literal

import numpy as np
from pydantic import Field, field_validator

from hybridfit import registry
from hybridfit.errors import HybridfitError, UnknownPluginError
from hybridfit.optimizer import Optimizer, Task
from hybridfit.plugin import Settings


class StepwiseSettings(Settings):
    optimizer: str = Field("pso", description="the optimiser run on each stage (a registered name)")
    optimizer_config: dict[str, Any] = Field(default_factory=dict, description="its settings")
    schedule: Literal["stepwise", "joint"] = Field("stepwise", description="stage by stage, or all parameters at once")
    root_share: float = Field(0.3, gt=0, lt=1, description="share of the budget for the global-pose stage")
    stage_weights: list[float] | None = Field(None, description="relative budget per stage (overrides root_share)")
    refine_share: float = Field(
        0.0, ge=0, lt=1, description="share of the budget for a final joint refinement of all parameters (0 = the paper)"
    )

    @field_validator("optimizer")
    @classmethod
    def _registered(cls, name: str) -> str:
        if name not in registry.names("optimizer"):
            try:
                registry.get("optimizer", name)
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


class Stepwise(Optimizer):
    """Runs any registered optimiser stage by stage (palm first, then fingers) or jointly."""

    Settings = StepwiseSettings

    @cached_property
    def inner(self) -> Optimizer:
        """The configured per-stage optimiser."""
        s = self.settings
        if s.optimizer in ("stepwise", self.name):
            raise HybridfitError(f"{self.name}: the inner optimizer cannot be a stepwise optimizer itself")
        return registry.create("optimizer", s.optimizer, s.optimizer_config)

    def _stages(self, task: Task):
        """The stages restricted to the task's parameters and points, with budget weights.

        Stages left with no free parameters or no points to score are skipped (their
        parameters stay at the task's base) and their budget goes to the others.
        """
        if self.settings.schedule == "joint":
            return [("joint", task.parameters, task.points)], [1.0]
        stages = task.problem.stage_points()
        w = self.settings.stage_weights
        if w is None:
            rest = (1.0 - self.settings.root_share) / (len(stages) - 1)
            w = [self.settings.root_share] + [rest] * (len(stages) - 1)
        elif len(w) != len(stages) or min(w) <= 0:
            raise HybridfitError(
                f"{self.name}: stage_weights needs {len(stages)} positive weights "
                f"({', '.join(s[0] for s in stages)}), got {w}"
            )
        kept, weights = [], []
        for (name, params, points), weight in zip(stages, w):
            params = np.intersect1d(params, task.parameters)
            points = np.intersect1d(points, task.points)
            if len(params) and len(points):
                kept.append((name, params, points))
                weights.append(weight)
        if not kept:
            return [("joint", task.parameters, task.points)], [1.0]
        # points no kept stage scores only add a constant: score them with the first stage
        # so that the stage losses still add up to the task's loss
        left = np.setdiff1d(task.points, np.concatenate([k[2] for k in kept]))
        kept[0] = (kept[0][0], kept[0][1], np.union1d(kept[0][2], left))
        return kept, weights

    def min_budget(self, task: Task) -> int:
        inner = self.inner
        stages, w = self._stages(task)
        w = np.asarray(w) / np.sum(w)
        share = 1.0 - (self.settings.refine_share if self.settings.schedule == "stepwise" else 0.0)
        need = [inner.min_budget(task.stage(n, p, q, task.budget)) / (s * share) for (n, p, q), s in zip(stages, w)]
        if share < 1.0:
            need.append(inner.min_budget(task) / (1.0 - share))
        return int(np.ceil(max(need)))

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        inner = self.inner
        stages, w = self._stages(task)
        refine = int(round(self.settings.refine_share * task.budget)) if self.settings.schedule == "stepwise" else 0
        for (name, params, points), budget in zip(stages, split_budget(task.budget - refine, w)):
            stage = task.stage(name, params, points, budget)
            inner.minimize(stage, rng)
            task.commit(stage)
        if refine:
            stage = task.stage("refine", task.parameters, task.points, refine)
            inner.minimize(stage, rng)
            task.commit(stage)


class StepwisePSOSettings(StepwiseSettings):
    optimizer: Literal["pso"] = Field("pso", description="always PSO")


class StepwisePSO(Stepwise):
    """The paper's optimiser: PSO stage by stage, palm first, then each finger."""

    Settings = StepwisePSOSettings
