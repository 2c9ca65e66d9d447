"""Settings of the synthetic depth data sets: the training grid and the TrackSeq-like test
sequence (what to render, with which model, camera, surface and sensor noise). Angles in
degrees, lengths in millimetres. See :mod:`.poses` for the poses and :mod:`.sets` for the
rendered sets."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from ..datasets.camera import Intrinsics
from ..errors import HybridfitError
from ..model.render import HandSurface
from ..plugin import format_validation_error
from .noise import SensorNoise

#: names of the test sequence's motions (each a series of key poses, :data:`.poses.MOTIONS`)
MOTION_NAMES = ("count", "pinch", "grasp", "wave", "ok")

DEFAULT_VIEWPOINTS = [(0, 0, 0), (35, 0, 0), (-35, 0, 0), (0, 35, 0), (0, -35, 0), (0, 0, 35), (0, 0, -35)]



class _Common(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, protected_namespaces=(), allow_inf_nan=False)

    model: str = Field("hand26", description="hand model plugin")
    model_settings: dict[str, Any] = Field(default_factory=dict, description="hand model settings")
    intrinsics: Intrinsics = Field(default_factory=Intrinsics, description="camera (default: the ICVL sensor)")
    surface: HandSurface = Field(default_factory=HandSurface, description="rendered hand surface geometry")
    noise: SensorNoise | None = Field(None, description="sensor noise model; None renders clean depth")
    seed: int = Field(0, ge=0, description="random seed (motions and noise)")
    distance_mm: float = Field(400.0, gt=0, description="distance of the palm centre from the camera, mm")


class GridConfig(_Common):
    """Training grid: per finger (a stage of the model) a list of articulations (degrees, the
    model's angle order for that stage) and the viewpoints as rotations (degrees) about the camera's x, y and
    z axes applied to a palm facing the camera (fingers up). Each frame's rotations, palm
    position and distance are jittered at random (uniformly within the ``*_jitter_*``
    ranges, from the stream ``numpy.random.default_rng([seed, 2])``, so a seed gives the same
    grid); set the three jitters to 0 for the exact viewpoints of the paper."""

    articulations_deg: dict[str, list[tuple[float, ...]]] | None = Field(
        None, description="per stage (finger) of the model, its articulations (the stage's angles in degrees); a "
        "stage not given stays at the default pose. None: the model's own (HandModel.grid_articulations_deg)")
    viewpoints_deg: list[tuple[float, float, float]] = Field(default_factory=lambda: list(DEFAULT_VIEWPOINTS), min_length=1)
    viewpoint_jitter_deg: float = Field(
        17.5, ge=0, le=90,
        description="each frame's rotations about the camera's x, y, z axes are its viewpoint's plus a deterministic "
                    "random offset drawn uniformly in [-j, j] degrees per axis (seeded by ``seed``); 0 renders the "
                    "exact viewpoints")
    position_jitter_mm: float = Field(30.0, ge=0, description="random lateral shift of each frame's palm centre in x and y, +- mm")
    distance_jitter_mm: float = Field(40.0, ge=0, description="random change of each frame's palm distance, +- mm")

    @model_validator(mode="after")
    def _non_empty(self):
        for finger, arts in (self.articulations_deg or {}).items():
            if not arts:
                raise ValueError(f"articulations_deg.{finger}: needs at least one articulation")
        if self.distance_jitter_mm >= self.distance_mm:
            raise ValueError("distance_jitter_mm must be smaller than distance_mm")
        return self


class SequenceConfig(_Common):
    """TrackSeq-like test sequence (frame counts of the slow raw motion before subsampling)."""

    frames: int = Field(400, ge=1, description="frames kept")
    subsample: int = Field(5, ge=1, description="keep every n-th frame of the slow motion (the paper: 5)")
    motions: list[str] = Field(default_factory=lambda: list(MOTION_NAMES), min_length=1, description=f"from {list(MOTION_NAMES)}")
    transition_frames: tuple[int, int] = Field((40, 80), description="raw frames from one key pose to the next (range)")
    hold_frames: tuple[int, int] = Field((0, 15), description="raw frames a key pose is held (range)")
    jitter_deg: float = Field(6.0, ge=0, description="standard deviation of the random change of each key-pose angle")
    orientation_frames: tuple[int, int] = Field((150, 300), description="raw frames between global orientation keys")
    max_tilt_deg: float = Field(
        20.0, ge=0, le=90,
        description="largest tilt of the palm away from the camera (default 20: a slow, modest drift of the global "
                    "orientation, closer to the paper's fixed-orientation TrackSeq; 35 before)")
    max_roll_deg: float = Field(20.0, ge=0, le=180, description="largest in-plane rotation (default 20; 40 before)")
    position_spread_mm: float = Field(30.0, ge=0, description="lateral drift of the palm centre, +- mm")
    depth_spread_mm: float = Field(40.0, ge=0, description="drift of the palm centre's distance, +- mm")

    @model_validator(mode="after")
    def _ranges(self):
        for name in ("transition_frames", "hold_frames", "orientation_frames"):
            lo, hi = getattr(self, name)
            if not (0 <= lo <= hi) or (name != "hold_frames" and lo < 1):
                raise ValueError(f"{name} must be a range 0 < low <= high, got ({lo}, {hi})")
        unknown = [m for m in self.motions if m not in MOTION_NAMES]
        if unknown:
            raise ValueError(f"unknown motions {unknown} (known: {', '.join(MOTION_NAMES)})")
        if self.depth_spread_mm >= self.distance_mm:
            raise ValueError("depth_spread_mm must be smaller than distance_mm")
        return self


def parse_config(cls, config=None, **overrides):
    """A config of class cls from None, a dict or a config, with overrides; a bad value
    raises HybridfitError with a one-line message."""
    base = config.model_dump() if isinstance(config, BaseModel) else dict(config or {})
    try:
        return cls(**{**base, **overrides})
    except ValidationError as err:
        raise HybridfitError(f"{cls.__name__}: {format_validation_error(err)}") from None
