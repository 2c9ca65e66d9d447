"""Study files: the schema of a study (pydantic models) and its validation messages.

A study names its data (``[data]``, one of five kinds), the base settings of every trial
(``[base]``: plugins and their configs, k, |P~|, budget), the sweep (``[sweep]``: a ``grid``
of dotted setting paths to value lists, and/or a list of ``variants``, each a table of
overrides deep-merged into the base), the seeds, the baselines and the report. A
``[quick]`` table holds overrides deep-merged into the whole file for ``--quick`` runs.
Reading a file is :mod:`.load`; expanding a study into trials is :mod:`.expand`.
"""

from __future__ import annotations

import difflib
import typing
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .. import registry
from ..datasets.skeletons import skeleton
from ..errors import HybridfitError
from ..keys import MAX_BUDGET, MAX_SEED
from ..fitting.tracking import TrackingSettings
from ..forest import ForestConfig
from ..synthetic.config import GridConfig, SequenceConfig
from ..synthetic.stress import StressSettings

PLOTS = ("success", "k", "proposal_set", "budget", "variants", "per_joint")
BASELINES = ("oracle", "top1")
METRICS = ("mean_error_mm", "median_error_mm", "fingertip_error_mm", "success_20mm", "success_40mm",
           "success_80mm", "objective", "evaluations", "time_per_frame_s", "failed_frames")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", protected_namespaces=(), populate_by_name=True)


class StudyTracking(TrackingSettings):
    """Tracking in a study: the ``hybridfit.fitting.tracking`` settings plus where the first frame
    starts and which frames are tracked."""

    first_frame: Literal["proposals", "ground-truth"] = Field(
        "proposals", description="frame 0's initial guess: its proposals, or the data's ground-truth model "
        "parameters (FORTH's set-up)")
    frame_step: int = Field(1, ge=1, description="track every n-th frame only (faster motion); the trial "
                            "reports those frames")


class TrialSettings(_Strict):
    """What one trial runs: plugins with their settings, proposals per joint k, |P~|, budget."""

    model: str = "hand26"
    model_settings: dict[str, Any] = Field(default_factory=dict, alias="model_config")
    objective: str = "clamped-then-soft-l1"
    objective_settings: dict[str, Any] = Field(default_factory=dict, alias="objective_config")
    optimizer: str = "stepwise-pso"
    optimizer_settings: dict[str, Any] = Field(default_factory=dict, alias="optimizer_config")
    k: int = Field(3, ge=1, description="proposals per joint (top k)")
    proposal_set: int = Field(200, ge=1, description="|P~|: votes per joint into mean-shift (forest data only)")
    budget: int = Field(3400, ge=1, le=MAX_BUDGET, description="objective evaluations per frame")
    search_radius_mm: float = Field(60.0, gt=0)
    skeleton: str | None = Field(None, description="the dataset skeleton of synthetic-stress data (a sweep "
                                 "dimension; icvl by default)")
    tracking: StudyTracking | None = Field(None, description="track the sequence (each frame starts from the "
                                           "previous fit) instead of fitting frames independently")

    @field_validator("model", "objective", "optimizer")
    @classmethod
    def _registered(cls, name: str, info):
        names = registry.names(info.field_name)
        if name not in names:
            close = difflib.get_close_matches(str(name), names, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ValueError(f"unknown {info.field_name} {name!r}{hint}; registered: {', '.join(names)}")
        return name

    @model_validator(mode="after")
    def _configs(self):
        for kind in ("model", "objective", "optimizer"):
            try:
                plugin = registry.create(kind, getattr(self, kind), getattr(self, f"{kind}_settings"))
                getattr(plugin, "inner", None)  # a wrapper's inner optimiser (stepwise) is checked too
            except HybridfitError as err:
                raise ValueError(f"{kind}_config: {err}") from None
        return self

    def as_dict(self) -> dict[str, Any]:
        """The settings as written in study files (``*_config`` keys; ``tracking`` only when set,
        so the keys of trials that do not track stay what they were)."""
        out = self.model_dump(mode="json", by_alias=True)
        for optional in ("tracking", "skeleton"):
            if out[optional] is None:
                del out[optional]
        return out


def _kind(value) -> str:
    """A TOML value's kind, for messages: 'a list', 'a table', 'a number', 'true/false'."""
    if isinstance(value, bool):
        return "true/false"
    return {list: "a list", dict: "a table", int: "a number", float: "a number"}.get(type(value),
                                                                                    type(value).__name__)


def _path(value, info):
    """A path field's value as given: a string (``file``: or a list of strings); anything else
    is one line saying what was expected (pydantic's own message names its internals)."""
    if value is None or isinstance(value, (str, Path)):
        return value
    if info.field_name == "file":
        if isinstance(value, list):
            bad = next((v for v in value if not isinstance(v, (str, Path))), None)
            if bad is None:
                return value
            raise ValueError(f"expected a path (a string) or a list of paths, got a list holding {_kind(bad)}")
        raise ValueError(f"expected a path (a string) or a list of paths, got {_kind(value)}")
    raise ValueError(f"expected a path (a string), got {_kind(value)}")


class SyntheticProposalsData(_Strict):
    """Proposals generated from the model (``hybridfit.synthetic_proposals``); trials use the top k."""

    kind: Literal["synthetic-proposals"]
    frames: int = Field(200, ge=1)
    k: int = Field(5, ge=1, description="proposals generated per joint; a trial's k must not exceed it")
    noise_mm: float = Field(5.0, ge=0)
    p_missing: float = Field(0.05, ge=0, le=1)
    p_true_top: float = Field(0.8, ge=0, le=1)
    distance_mm: float = Field(400.0, gt=0)
    seed: int = 2015


class SyntheticDepthData(_Strict):
    """The synthetic depth data: training grid + TrackSeq-like test sequence, a forest trained on it."""

    kind: Literal["synthetic-depth"]
    train: GridConfig = Field(default_factory=GridConfig)
    test: SequenceConfig = Field(default_factory=SequenceConfig)
    forest: ForestConfig = Field(default_factory=ForestConfig)
    train_subset: int | None = Field(None, ge=1, description="train on this many grid frames drawn at random")
    stride: int = Field(2, ge=1, description="pixel step of the dense sampling at test time")
    bandwidth_mm: float = Field(10.0, gt=0, description="test-time mean-shift bandwidth")


class DatasetData(_Strict):
    """Data-set folders (``hybridfit.datasets.folder``): a test set and a training set or a trained forest."""

    kind: Literal["dataset"]
    test: Path
    train: Path | None = None
    forest: ForestConfig = Field(default_factory=ForestConfig)
    forest_file: Path | None = Field(None, description="a trained forest (.npz) instead of training one")
    train_subset: int | None = Field(None, ge=1)
    frames: int | None = Field(None, ge=1, description="first n test frames (default: all)")
    stride: int = Field(2, ge=1)
    bandwidth_mm: float = Field(10.0, gt=0)

    _paths = field_validator("test", "train", "forest_file", mode="before")(_path)

    @model_validator(mode="after")
    def _source(self):
        if (self.train is None) == (self.forest_file is None):
            raise ValueError("give exactly one of train (a data-set folder to train on) and forest_file")
        return self


class Calibration(_Strict):
    """Calibrate the trial's model on ground-truth frames (``hybridfit.fitting.calibrate``), a cached shared step."""

    frames: str = Field("0:100", description="START:STOP of the ground truth to calibrate on")
    rounds: int = Field(3, ge=0)
    budget: int = Field(3400, ge=1)
    seed: int = 0
    hand: Literal["auto", "right", "left"] = "auto"


class ProposalsData(_Strict):
    """A proposals file: an .npz (proposals, confidences, joint_names?, ground_truth?) or
    results files (common format, one proposal per joint per file) with a dataset skeleton."""

    kind: Literal["proposals"]
    file: Path | list[Path]
    dataset: str | None = Field(None, description="skeleton: a built-in name (icvl, nyu, nyu36, msra, mediapipe, "
                                "mano) or a skeleton .toml file, relative to the study file")
    ground_truth: Path | None = Field(None, description="ground truth in the results format (else from the npz)")
    frames: str | None = Field(None, description="START:STOP of the frames to fit (default: all)")
    calibrate: Calibration | None = Field(None, description="calibrate the model on the ground truth first")

    _paths = field_validator("file", "ground_truth", mode="before")(_path)

    @field_validator("file")
    @classmethod
    def _one_npz(cls, file):
        if isinstance(file, list) and len(file) > 1 and any(f.suffix == ".npz" for f in file):
            npz = next(f for f in file if f.suffix == ".npz")
            raise ValueError("a list is for results files (one file per proposal rank, with dataset); an .npz holds "
                             f"every proposal: give one, file = \"{npz}\"")
        return file

    @model_validator(mode="after")
    def _needs(self):
        files = self.file if isinstance(self.file, list) else [self.file]
        if any(f.suffix != ".npz" for f in files) and self.dataset is None:
            raise ValueError("results files need dataset (a skeleton name or .toml file)")
        if self.calibrate is not None and (self.ground_truth is None or self.dataset is None):
            raise ValueError("calibrate needs ground_truth and dataset")
        return self


class StressCalibration(_Strict):
    """Calibrate the model on annotated frames of the same subject before the fitted frames."""

    frames: int = Field(100, ge=1, description="annotated frames to calibrate on (never fitted)")
    rounds: int = Field(2, ge=0)
    budget: int = Field(3400, ge=1)
    seed: int = 0


class SyntheticStressData(_Strict):
    """Synthetic stress data like real annotations (``hybridfit.synthetic.stress``), one sequence per
    skeleton (the trials' ``skeleton`` setting): calibration frames, then the fitted frames."""

    kind: Literal["synthetic-stress"]
    frames: int = Field(300, ge=1, description="fitted frames per skeleton")
    k: int = Field(3, ge=1, description="proposals generated per point; a trial's k must not exceed it")
    seed: int = 2026
    stress: StressSettings = Field(default_factory=StressSettings)
    calibrate: StressCalibration | None = Field(default_factory=StressCalibration)


Data = Annotated[Union[SyntheticProposalsData, SyntheticDepthData, DatasetData, ProposalsData, SyntheticStressData],
                 Field(discriminator="kind")]


class Sweep(_Strict):
    grid: dict[str, list[Any]] = Field(default_factory=dict, description="dotted setting path -> values")
    variants: list[dict[str, Any]] = Field(default_factory=list, description="override tables (optional 'name')")


class Report(_Strict):
    plots: list[Literal[PLOTS]] | Literal["auto"] = "auto"  # type: ignore[valid-type]
    metrics: list[Literal[METRICS]] = Field(  # type: ignore[valid-type]
        default_factory=lambda: ["mean_error_mm", "fingertip_error_mm", "success_20mm", "success_40mm",
                                 "success_80mm", "time_per_frame_s"], description="columns of the report's table")
    per_joint_variants: int = Field(12, ge=1, description="at most this many variants in the per-joint plot "
                                    "(the Oracle aside; any left out are named in its title)")


class Study(_Strict):
    name: str
    description: str = ""
    seed: int = Field(0, ge=0, le=MAX_SEED, description="study seed: derives the trial seeds when seeds is a count")
    seeds: int | list[int] = Field(1, description="a count of derived seeds, or the seeds themselves")
    data: Data
    base: TrialSettings = Field(default_factory=TrialSettings)
    sweep: Sweep = Field(default_factory=Sweep)
    baselines: list[Literal[BASELINES]] = Field(default_factory=lambda: list(BASELINES))  # type: ignore[valid-type]
    report: Report = Field(default_factory=Report)
    quick: dict[str, Any] = Field(default_factory=dict, description="overrides for --quick")

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, v):
        if isinstance(v, int) and v < 1 or isinstance(v, list) and (not v or len(set(v)) != len(v)):
            raise ValueError("need a count >= 1 or a non-empty list of distinct seeds")
        if isinstance(v, list) and not all(0 <= s <= MAX_SEED for s in v):
            raise ValueError("seeds are integers from 0 to 2**64 - 1")
        if isinstance(v, int) and v > 10**6:
            raise ValueError(f"a count of at most 1,000,000 seeds, got {v}")
        return v

    def seed_list(self) -> list[int]:
        """The trial seeds (derived from ``seed`` when ``seeds`` is a count)."""
        if isinstance(self.seeds, list):
            return list(self.seeds)
        return [int(s) for s in np.random.SeedSequence(self.seed).generate_state(self.seeds)]


def validation_error(where: str, err: ValidationError, prefix: str = "") -> HybridfitError:
    parts = []
    for e in err.errors():
        path = [str(p) for p in (prefix, *e["loc"]) if p != ""]
        path = [p for i, p in enumerate(path) if not (i and path[i - 1] == "data" and p in _KINDS.split(", "))]
        loc = ".".join(path) or "(study)"
        msg = _unknown_key(e["loc"]) if e["type"] == "extra_forbidden" else e["msg"].removeprefix("Value error, ")
        if e["type"] in ("union_tag_invalid", "union_tag_not_found"):
            given = str((e.get("ctx") or {}).get("tag", ""))
            close = difflib.get_close_matches(given, _KINDS.split(", "), n=1) if given else []
            msg = f"kind must be one of {_KINDS}" + (f" (did you mean {close[0]!r}?)" if close else "")
        parts.append(f"{loc}: {msg}")
    return HybridfitError(f"{where}: " + "; ".join(parts))


def _models(annotation) -> list[type[BaseModel]]:
    """The pydantic models inside a type annotation (through Optional, Union, Annotated, list)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for arg in typing.get_args(annotation) for m in _models(arg)]


def _unknown_key(loc) -> str:
    """'unknown key' with the closest valid key of the table it is in."""
    models: list[type[BaseModel]] = [Study]
    for part in loc[:-1]:
        fields = [f for m in models for n, f in m.model_fields.items() if part in (n, f.alias)]
        tagged = [m for m in models if typing.get_args(m.model_fields.get("kind", Field()).annotation) == (part,)]
        models = tagged or [m for f in fields for m in _models(f.annotation)]
    names = [f.alias or n for m in models for n, f in m.model_fields.items()]
    close = difflib.get_close_matches(str(loc[-1]), names, n=1) if loc else []
    return f"unknown key (did you mean {close[0]!r}?)" if close else "unknown key"


#: the data kinds, from the [data] tables' ``kind`` literals (so a new kind is always listed)
_KINDS = ", ".join(typing.get_args(m.model_fields["kind"].annotation)[0] for m in typing.get_args(typing.get_args(Data)[0]))
SETTING_KEYS = {f.alias or n for n, f in TrialSettings.model_fields.items()}


