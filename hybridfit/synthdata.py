"""The synthetic data sets of the paper's experiments: a training grid and a TrackSeq-like
test sequence, rendered with :mod:`hybridfit.render` and written with :mod:`hybridfit.dataset`.

Training grid: a few articulations per finger (default 4), every combination of them
(4^5 = 1024 hand shapes), each seen from several viewpoints (default 7: 7168 frames),
the palm facing the camera at ``distance_mm``. Frame index = shape * viewpoints + viewpoint;
shapes enumerate the fingers' articulations with the thumb slowest. By default every frame
also gets its own deterministic random change of the global pose (``viewpoint_jitter_deg``
+-17.5 degrees about each camera axis, half the spacing of the default viewpoints;
``position_jitter_mm`` +-30 and ``distance_jitter_mm`` +-40, the test sequence's drift), so
the 7168 frames cover the orientations and positions between the 7 exact viewpoints. With
the exact viewpoints and distance (all three 0) the paper's forest (3 trees, depth 23)
memorises the grid (1 mm top-proposal error on training frames) and generalises poorly: on
the test sequence with tilt 35 / roll 40 degrees its top proposal is off by 34.0 mm on
average (Oracle k=3 17.1 mm), with the jitter by 7.7 mm (Oracle 4.9 mm); on the default
sequence 33.7 -> 5.0 mm (benchmarks/bench_forest.py, default ForestConfig). The distance
jitter matters most: a depth feature with one probe on the background reads
``background_mm`` minus the hand's depth, so a forest trained at one distance splits on
absolute depth (62% of its splits threshold such a reading) and fails once the hand moves
by a few centimetres.

Test sequence: natural motions (counting, pinching, grasping, finger waves, an OK sign)
as key poses perturbed at random (so none is a training pose), interpolated smoothly in
joint-angle space with holds, while the global orientation and position drift slowly
between random keys; every ``subsample``-th frame of this slow motion is kept, as in the
paper's TrackSeq. The paper's TrackSeq keeps the global pose fixed; ours drifts slowly,
by default within a tilt and an in-plane roll of 20 degrees of the frontal palm (inside the
training grid's +-35 degree viewpoints), +-30 mm laterally and +-40 mm in distance. Larger
ranges (``max_tilt_deg``, ``max_roll_deg``; up to 35 / 40 degrees before) make a harder
test of the forest's viewpoint generalisation. Angles in degrees in the configs, radians
in the parameters.
"""

from __future__ import annotations

import itertools
import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from . import registry
from .camera import Intrinsics, xyz_to_uvd
from .dataset import write_dataset
from .errors import HybridfitError
from .geometry import axis_angle_matrix, matrix_to_quaternion, slerp
from .noise import SensorNoise, apply_noise
from .plugin import format_validation_error
from .render import HandSurface, Renderer
from .synthetic import PALM_TO_CAMERA, palm_orientation

# per-finger angles in degrees in the model's parameter order: thumb (CMC flexion, CMC
# abduction, MCP, IP), fingers (MCP flexion, MCP abduction, PIP, DIP)
_THUMB = {"open": (-12, -25, 5, 3), "rest": (8, 0, 12, 10), "across": (45, 35, 35, 25),
          "pinch": (40, 10, 30, 25), "grasp": (25, 15, 20, 15)}
_FINGER = {"straight": (3, 0, 3, 2), "fist": (85, 0, 95, 65), "rest": (15, 0, 20, 10), "half": (40, 0, 45, 25),
           "grasp": (50, 0, 55, 35), "pinch": (45, 0, 35, 20), "wave": (60, 0, 70, 40)}
_SPREAD = (-10, -2, 6, 12)  # abduction of index .. little in an open hand


def _hand(thumb: str, *fingers: str, spread: bool = False) -> np.ndarray:
    """(20,) degrees: a thumb state and four finger states (index .. little)."""
    out = [_THUMB[thumb]]
    for i, f in enumerate(fingers):
        a = list(_FINGER[f])
        if spread and f == "straight":
            a[1] = _SPREAD[i]
        out.append(a)
    return np.array(out, float).ravel()


KEY_POSES = {
    "open": _hand("open", "straight", "straight", "straight", "straight", spread=True),
    "rest": _hand("rest", "rest", "rest", "rest", "rest"),
    "fist": _hand("across", "fist", "fist", "fist", "fist"),
    "one": _hand("across", "straight", "fist", "fist", "fist"),
    "two": _hand("across", "straight", "straight", "fist", "fist", spread=True),
    "three": _hand("across", "straight", "straight", "straight", "fist", spread=True),
    "four": _hand("across", "straight", "straight", "straight", "straight", spread=True),
    "pinch_open": _hand("open", "half", "rest", "rest", "rest"),
    "pinch": _hand("pinch", "pinch", "half", "half", "half"),
    "grasp": _hand("grasp", "grasp", "grasp", "grasp", "grasp"),
    "ok": _hand("pinch", "pinch", "straight", "straight", "straight", spread=True),
    **{f"wave{i}": _hand("open", *["wave" if k == i else "straight" for k in range(4)]) for i in range(4)},
}
MOTIONS = {
    "count": ("fist", "one", "two", "three", "four", "open"),
    "pinch": ("rest", "pinch_open", "pinch", "pinch_open", "pinch", "rest"),
    "grasp": ("open", "grasp", "fist", "grasp", "open"),
    "wave": ("open", "wave0", "wave1", "wave2", "wave3", "open"),
    "ok": ("rest", "ok", "open", "ok", "rest"),
}

DEFAULT_ARTICULATIONS = {
    "thumb": [(-10, -20, 5, 0), (10, 0, 20, 15), (40, 30, 30, 20), (55, 20, 60, 60)],
    **{f: [(5, 0, 5, 5), (30, 0, 50, 30), (60, 0, 10, 5), (80, 0, 100, 70)] for f in ("index", "middle", "ring", "little")},
}
DEFAULT_VIEWPOINTS = [(0, 0, 0), (35, 0, 0), (-35, 0, 0), (0, 35, 0), (0, -35, 0), (0, 0, 35), (0, 0, -35)]


class _Common(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, protected_namespaces=())

    model: str = Field("hand26", description="hand model plugin")
    model_settings: dict[str, Any] = Field(default_factory=dict, description="hand model settings")
    intrinsics: Intrinsics = Field(default_factory=Intrinsics, description="camera (default: the ICVL sensor)")
    surface: HandSurface = Field(default_factory=HandSurface, description="rendered hand surface geometry")
    noise: SensorNoise | None = Field(None, description="sensor noise model; None renders clean depth")
    seed: int = Field(0, ge=0, description="random seed (motions and noise)")
    distance_mm: float = Field(400.0, gt=0, description="distance of the palm centre from the camera, mm")


class GridConfig(_Common):
    """Training grid: per finger a list of articulations (degrees, the model's angle order
    for that finger) and the viewpoints as rotations (degrees) about the camera's x, y and
    z axes applied to a palm facing the camera (fingers up). Each frame's rotations, palm
    position and distance are jittered at random (uniformly within the ``*_jitter_*``
    ranges, from the stream ``numpy.random.default_rng([seed, 2])``, so a seed gives the same
    grid); set the three jitters to 0 for the exact viewpoints of the paper."""

    articulations_deg: dict[str, list[tuple[float, ...]]] = Field(
        default_factory=lambda: {k: list(v) for k, v in DEFAULT_ARTICULATIONS.items()})
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
        for finger, arts in self.articulations_deg.items():
            if not arts:
                raise ValueError(f"articulations_deg.{finger}: needs at least one articulation")
        if self.distance_jitter_mm >= self.distance_mm:
            raise ValueError("distance_jitter_mm must be smaller than distance_mm")
        return self


class SequenceConfig(_Common):
    """TrackSeq-like test sequence (frame counts of the slow raw motion before subsampling)."""

    frames: int = Field(400, ge=1, description="frames kept")
    subsample: int = Field(5, ge=1, description="keep every n-th frame of the slow motion (the paper: 5)")
    motions: list[str] = Field(default_factory=lambda: list(MOTIONS), min_length=1, description=f"from {list(MOTIONS)}")
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
        unknown = [m for m in self.motions if m not in MOTIONS]
        if unknown:
            raise ValueError(f"unknown motions {unknown} (known: {', '.join(MOTIONS)})")
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


def _model(config: _Common):
    return registry.create("model", config.model, config.model_settings)


def _finger_slices(model) -> dict[str, list[int]]:
    """Finger name -> indices of its angle parameters (by the parameter name prefix)."""
    out: dict[str, list[int]] = {}
    for i, name in enumerate(model.parameter_names[7:], start=7):
        out.setdefault(name.split("_")[0], []).append(i)
    return out


def _orientation(about_xyz_deg) -> np.ndarray:
    """(4,) quaternion of a palm facing the camera rotated about the camera's x, y, z axes."""
    ax, ay, az = np.radians(about_xyz_deg)
    R = axis_angle_matrix([0, 0, 1], az) @ axis_angle_matrix([0, 1, 0], ay) @ axis_angle_matrix([1, 0, 0], ax)
    return matrix_to_quaternion(R @ PALM_TO_CAMERA)


def grid_poses(config: GridConfig | Mapping | None = None, model=None) -> np.ndarray:
    """(shapes * viewpoints, P) parameters of the training grid."""
    config = parse_config(GridConfig, config)
    model = model or _model(config)
    lower, upper = model.bounds()
    fingers = _finger_slices(model)
    unknown = set(config.articulations_deg) - set(fingers)
    if unknown:
        raise HybridfitError(f"articulations_deg: unknown fingers {sorted(unknown)} (the model has {', '.join(fingers)})")
    choices = []
    for finger, idx in fingers.items():
        arts = np.radians(np.array(config.articulations_deg.get(finger, [np.degrees(model.default_params()[idx])]), float))
        if arts.ndim != 2 or arts.shape[1] != len(idx):
            raise HybridfitError(f"articulations_deg.{finger}: each articulation needs {len(idx)} angles "
                                 f"({', '.join(model.parameter_names[i] for i in idx)})")
        outside = (arts < lower[idx] - 1e-9) | (arts > upper[idx] + 1e-9)
        if outside.any():
            a, k = np.argwhere(outside)[0]
            raise HybridfitError(
                f"articulations_deg.{finger}[{a}]: {model.parameter_names[idx[k]]} = {np.degrees(arts[a, k]):g} deg is "
                f"outside the model's limits [{np.degrees(lower[idx[k]]):g}, {np.degrees(upper[idx[k]]):g}]")
        choices.append((idx, arts))
    views = np.array(config.viewpoints_deg, float)
    base = model.default_params()
    base[0:3] = (0.0, 0.0, config.distance_mm)
    rows = []
    for combo in itertools.product(*[range(len(arts)) for _, arts in choices]):
        shape = base.copy()
        for (idx, arts), c in zip(choices, combo):
            shape[idx] = arts[c]
        rows.append(np.tile(shape, (len(views), 1)))
    X = np.concatenate(rows)
    # per-frame jitter of the global pose from its own stream: the articulations and the
    # frame order do not depend on it, and the same seed gives the same grid
    rng = np.random.default_rng([config.seed, 2])
    n = len(X)
    about = np.tile(views, (n // len(views), 1)) + rng.uniform(-1, 1, (n, 3)) * config.viewpoint_jitter_deg
    shift = rng.uniform(-1, 1, (n, 3)) * (config.position_jitter_mm, config.position_jitter_mm, config.distance_jitter_mm)
    X[:, 0:3] += shift
    X[:, 3:7] = [_orientation(a) for a in about]
    return X


def _smooth(times: np.ndarray, key_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Segment index and smoothstep weight of each time between increasing key times."""
    i = np.clip(np.searchsorted(key_t, times, side="right") - 1, 0, len(key_t) - 2)
    s = np.clip((times - key_t[i]) / np.maximum(key_t[i + 1] - key_t[i], 1e-9), 0.0, 1.0)
    return i, s * s * (3.0 - 2.0 * s)




def sequence_poses(config: SequenceConfig | Mapping | None = None, model=None) -> np.ndarray:
    """(frames, P) parameters of the test sequence (deterministic for a seed)."""
    config = parse_config(SequenceConfig, config)
    model = model or _model(config)
    lower, upper = model.bounds()
    angles = np.arange(7, model.n_params)
    if len(angles) != 20:
        raise HybridfitError(f"the test sequence's key poses need a model with 20 finger angles, {config.model} has {len(angles)}")
    # separate streams: a shorter sequence is a prefix of a longer one with the same seed
    rng = np.random.default_rng([config.seed, 0])
    rng_global = np.random.default_rng([config.seed, 1])
    end = (config.frames - 1) * config.subsample
    # finger articulation keys: motions in random order, each key held, then a smooth transition
    key_t, key_v, t = [], [], 0
    while not key_t or key_t[-1] <= end:  # until a key lies beyond the end
        for name in MOTIONS[config.motions[rng.integers(len(config.motions))]]:
            pose = np.clip(np.radians(KEY_POSES[name] + rng.normal(0, config.jitter_deg, 20)), lower[angles], upper[angles])
            hold = int(rng.integers(config.hold_frames[0], config.hold_frames[1] + 1))
            key_t += [t, t + hold]
            key_v += [pose, pose]
            t += hold + int(rng.integers(config.transition_frames[0], config.transition_frames[1] + 1))
    # global pose keys
    glob_t, glob_q, glob_p, t = [], [], [], 0
    while not glob_t or glob_t[-1] <= end:
        phi = rng_global.uniform(0, 2 * np.pi)
        tilt = rng_global.uniform(0, config.max_tilt_deg)
        glob_q.append(palm_orientation(phi, tilt, rng_global.uniform(-config.max_roll_deg, config.max_roll_deg)))
        s = config.position_spread_mm
        glob_p.append([rng_global.uniform(-s, s), rng_global.uniform(-s, s),
                       config.distance_mm + rng_global.uniform(-config.depth_spread_mm, config.depth_spread_mm)])
        glob_t.append(t)
        t += int(rng_global.integers(config.orientation_frames[0], config.orientation_frames[1] + 1))

    times = np.arange(config.frames, dtype=float) * config.subsample
    X = np.tile(model.default_params(), (config.frames, 1))
    key_t, key_v = np.array(key_t, float), np.array(key_v)
    i, w = _smooth(times, key_t)
    X[:, angles] = key_v[i] + w[:, None] * (key_v[i + 1] - key_v[i])
    glob_t, glob_q, glob_p = np.array(glob_t, float), np.array(glob_q), np.array(glob_p)
    i, w = _smooth(times, glob_t)
    X[:, 0:3] = glob_p[i] + w[:, None] * (glob_p[i + 1] - glob_p[i])
    X[:, 3:7] = slerp(glob_q[i], glob_q[i + 1], w)
    return X


def check_in_image(joints: np.ndarray, intrinsics: Intrinsics, joint_names) -> None:
    """Refuse frames whose joints (F, J, 3) mm project outside the image or lie behind the camera."""
    uvd = xyz_to_uvd(joints, intrinsics)
    out = (uvd[..., 2] <= 0) | (uvd[..., 0] < 0) | (uvd[..., 0] > intrinsics.width - 1) \
        | (uvd[..., 1] < 0) | (uvd[..., 1] > intrinsics.height - 1)
    if out.any():
        f, j = np.argwhere(out)[0]
        u, v, d = uvd[f, j]
        raise HybridfitError(
            f"the hand leaves the {intrinsics.width}x{intrinsics.height} image in frame {f} ({joint_names[j]} at "
            f"u={u:.0f}, v={v:.0f}, depth {d:.0f} mm); change the distance or the intrinsics")


def render_poses(params: np.ndarray, config: _Common, model=None, *, progress: bool = False, chunk: int = 128,
                 jobs: int | None = None):
    """Render (F, P) parameters with the config's camera, surface and noise:
    depth (F, H, W) uint16, parts (F, H, W) uint8, joints (F, J, 3) mm. Chunks of frames
    render in ``jobs`` threads (default: one per CPU); the result does not depend on it."""
    model = model or _model(config)
    if not np.isfinite(params).all():
        bad = int(np.argmax(~np.isfinite(params).all(axis=1)))
        raise HybridfitError(f"pose of frame {bad} has NaN or inf values")
    joints = model.forward(params)
    check_in_image(joints, config.intrinsics, model.joint_names)
    renderer = Renderer(model, config.intrinsics, config.surface)
    k = config.intrinsics
    depth = np.empty((len(params), k.height, k.width), np.uint16)
    parts = np.empty((len(params), k.height, k.width), np.uint8)

    def work(s: int) -> None:
        d, p = renderer.render_joints(joints[s:s + chunk])
        if config.noise is not None:
            d, p = apply_noise(d, p, k, config.noise, config.seed, first_frame=s)
        depth[s:s + chunk], parts[s:s + chunk] = d, p

    starts = range(0, len(params), chunk)
    with ThreadPoolExecutor(jobs or os.cpu_count() or 1) as pool:
        done = pool.map(work, starts)
        if progress:
            from tqdm import tqdm

            done = tqdm(done, total=len(starts), desc="rendering", unit="chunk")
        for _ in done:
            pass
    return depth, parts, joints


def _make(out, config: _Common, params: np.ndarray, generator: str, progress: bool) -> Path:
    model = _model(config)
    depth, parts, joints = render_poses(params, config, model, progress=progress)
    meta = {"generator": generator, "config": config.model_dump(mode="json"), "seed": config.seed,
            "parents": [int(p) for p in model.parents]}
    return write_dataset(out, depth, parts, joints, params, config.intrinsics, model.joint_names, meta, progress=progress)


def make_train(out, config: GridConfig | Mapping | None = None, *, progress: bool = False,
               frames: Sequence[int] | None = None) -> Path:
    """Render and write the training grid data set to the folder ``out``; with ``frames``
    (indices into the grid) only those frames, in that order (without sensor noise they are
    the same images as in the whole grid)."""
    config = parse_config(GridConfig, config)
    params = grid_poses(config)
    return _make(out, config, params if frames is None else params[np.asarray(frames, np.int64)],
                 "hybridfit.synthdata.make_train", progress)


def make_test(out, config: SequenceConfig | Mapping | None = None, *, progress: bool = False) -> Path:
    """Render and write the TrackSeq-like test sequence data set to the folder ``out``."""
    config = parse_config(SequenceConfig, config)
    return _make(out, config, sequence_poses(config), "hybridfit.synthdata.make_test", progress)
