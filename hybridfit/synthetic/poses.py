"""The poses of the synthetic data sets: a training grid and a TrackSeq-like test sequence
(settings in :mod:`.config`; rendered and written by :mod:`.sets`).

Training grid: a few articulations per finger (the default model's: 4), every combination of them
(4^5 = 1024 hand shapes), each seen from several viewpoints (default 7: 7168 frames),
the palm facing the camera at ``distance_mm``. Frame index = shape * viewpoints + viewpoint;
shapes enumerate the fingers' articulations with the thumb slowest. By default every frame
also gets its own deterministic random change of the global pose (``viewpoint_jitter_deg``
+-17.5 degrees about each camera axis, half the spacing of the default viewpoints;
``position_jitter_mm`` +-30 and ``distance_jitter_mm`` +-40, the test sequence's drift), so
the 7168 frames cover the orientations and positions between the 7 exact viewpoints.
Without the jitter (all three 0: the paper's exact viewpoints) the forest memorises the
grid and generalises poorly (the figures: the docs' results page, section "Training-grid
jitter"). The distance jitter matters most: a depth feature with one probe on the
background reads ``background_mm`` minus the hand's depth, so a forest trained at one
distance splits on absolute depth and fails once the hand moves by a few centimetres.

Both ask the model, never a name: the grid's articulations per stage come from
``HandModel.grid_articulations_deg`` (a stage it does not give: 4 articulations at
``FALLBACK_SHARES`` of each angle's range), the sequence's key poses from
``HandModel.named_poses_deg`` (a pose it does not name: a random shape, each angle uniform
in the central ``RANDOM_SHAPE_SHARE`` of its range, drawn from the sequence's stream).

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
from typing import Mapping

import numpy as np

from .. import registry
from ..errors import HybridfitError
from ..model.rotations import axis_angle_matrix, matrix_to_quaternion, slerp
from .config import GridConfig, SequenceConfig, _Common, parse_config
from .proposals import PALM_TO_CAMERA, palm_orientation

#: the test sequence's motions: series of key poses, named poses of the model
#: (``HandModel.named_poses_deg``); a pose the model does not name becomes a random shape
MOTIONS = {
    "count": ("fist", "one", "two", "three", "four", "open"),
    "pinch": ("rest", "pinch_open", "pinch", "pinch_open", "pinch", "rest"),
    "grasp": ("open", "grasp", "fist", "grasp", "open"),
    "wave": ("open", "wave0", "wave1", "wave2", "wave3", "open"),
    "ok": ("rest", "ok", "open", "ok", "rest"),
}

def _model(config: _Common):
    return registry.create("model", config.model, config.model_settings)


def _stage_angles(model) -> dict[str, list[int]]:
    """Stage name -> indices of its angle parameters, for the stages after the global pose's."""
    return {s.name: list(s.parameters) for s in model.stages() if min(s.parameters) >= 7}


#: shares of each angle's range (lower to upper) of the 4 articulations a grid stage gets when
#: neither the config nor the model gives it any
FALLBACK_SHARES = (0.1, 0.37, 0.63, 0.9)
#: share of each angle's range, about its middle, that the test sequence's random shapes use
RANDOM_SHAPE_SHARE = 0.8


def _fallback_articulations(model, idx: list[int]) -> np.ndarray:
    """(4, n) degrees: a stage's angles at ``FALLBACK_SHARES`` of their ranges (an unbounded
    angle stays at its default)."""
    lower, upper = model.bounds()
    lo, hi, x0 = lower[idx], upper[idx], model.default_params()[idx]
    finite = np.isfinite(lo) & np.isfinite(hi)
    shares = np.asarray(FALLBACK_SHARES)[:, None]
    return np.degrees(np.where(finite, np.where(finite, lo, 0) + shares * np.where(finite, hi - lo, 0), x0))


def _random_shape(model, rng: np.random.Generator) -> np.ndarray:
    """(P - 7,) radians: every angle uniform in the central ``RANDOM_SHAPE_SHARE`` of its range
    (an unbounded angle stays at its default)."""
    lower, upper = model.bounds()
    lo, hi, x0 = lower[7:], upper[7:], model.default_params()[7:]
    finite = np.isfinite(lo) & np.isfinite(hi)
    mid, half = np.where(finite, (lo + hi) / 2, x0), np.where(finite, (hi - lo) / 2, 0.0) * RANDOM_SHAPE_SHARE
    return mid + half * rng.uniform(-1.0, 1.0, len(lo))


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
    fingers = _stage_angles(model)
    if config.articulations_deg is None:
        given = dict(model.grid_articulations_deg())
        given.update({f: _fallback_articulations(model, idx) for f, idx in fingers.items() if f not in given})
    else:
        given = config.articulations_deg
    unknown = set(given) - set(fingers)
    if unknown:
        raise HybridfitError(f"articulations_deg: unknown fingers {sorted(unknown)} (the model has {', '.join(fingers)})")
    choices = []
    for finger, idx in fingers.items():
        arts = np.radians(np.array(given.get(finger, [np.degrees(model.default_params()[idx])]), float))
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


def grid_subset(n: int, count: int | None, seed: int) -> np.ndarray | None:
    """``count`` of a grid's ``n`` frames drawn at random (``numpy.random.default_rng(seed)``),
    sorted: spread over every articulation and viewpoint, where the grid's first frames hold one
    articulation of the first fingers. None (the whole grid) when ``count`` is None or at least ``n``."""
    if count is None or count >= n:
        return None
    return np.sort(np.random.default_rng(seed).choice(n, count, replace=False))


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
    named = model.named_poses_deg()
    for name, pose in named.items():
        if np.shape(pose) != angles.shape:
            raise HybridfitError(f"model {config.model}: named pose {name!r} has {np.size(pose)} angles, the model has "
                                 f"{len(angles)}")
    # separate streams: a shorter sequence is a prefix of a longer one with the same seed
    rng = np.random.default_rng([config.seed, 0])
    rng_global = np.random.default_rng([config.seed, 1])
    end = (config.frames - 1) * config.subsample
    # finger articulation keys: motions in random order, each key held, then a smooth transition
    key_t, key_v, t = [], [], 0
    while not key_t or key_t[-1] <= end:  # until a key lies beyond the end
        for name in MOTIONS[config.motions[rng.integers(len(config.motions))]]:
            if name in named:
                pose = np.clip(np.radians(named[name] + rng.normal(0, config.jitter_deg, len(angles))),
                               lower[angles], upper[angles])
            else:
                pose = _random_shape(model, rng)
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
