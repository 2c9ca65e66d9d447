"""``hand26``: the paper's 26-DoF joints-only hand model (27 parameters, 21 joints).

Parameters (27): palm centre position x, y, z (mm); orientation quaternion w, x, y, z
(normalised inside the model); then per finger (thumb, index, middle, ring, little) four
angles in radians: base flexion, base abduction, and two hinge flexions. Joints (21):
the wrist, then per finger its base joint, two further joints and the tip (for the thumb:
CMC, MCP, IP, tip; for the other fingers: MCP, PIP, DIP, tip).

Hand frame (right hand, before the global rotation): x radial (towards the thumb), y
distal (wrist to fingers), z palmar (out of the palm). The origin is the palm centre: the
mean of the wrist and the four finger MCPs (the derived point ``palm_centre``). Flexion is
positive towards the palm, abduction positive towards the little finger. ``mirror=True``
gives the left hand (x negated in the hand frame).

Anatomical limits (degrees; static constraints):
- fingers, Lin, Wu & Huang, "Modeling the constraints of human hand motion", IEEE HUMO
  2000: MCP flexion 0..90, MCP abduction -15..15, PIP 0..110, DIP 0..90;
- thumb, active ranges of motion of the American Academy of Orthopaedic Surgeons (Greene &
  Heckman, "The clinical measurement of joint motion", 1994), as used for the thumb by
  model-based trackers (Oikonomidis et al., BMVC 2011): CMC flexion -20..60 and
  abduction -30..40 (the thumb's rest frame already points it away from the palm), MCP
  0..80, IP -20..90 (the IP joint hyperextends).

Default bone lengths are those of an average adult hand (about 190 mm long): phalanx
lengths after Buchholz, Armstrong & Goldstein, "Anthropometric data for describing the
kinematics of the human hand", Ergonomics 1992 (ratios of hand length), rounded to mm.

Calibratable geometry (``geometry()`` / ``with_geometry()``): the 15 bone lengths, the 15
coordinates of the five finger base positions (mm), the 30 bone offsets (mm) and the
weights of the derived points in the ``derived_points`` setting. A bone's offset moves its
end joint across the bone, in the bone's frame (x along the flexion axis, z palmar), off
the straight line along its rest direction: where a dataset's annotated points sit off
the joint centres (surface labels, another hand model's joints), as marker offsets do.
For a tip it is exactly a marker offset; for an inner joint the joints beyond it move
with it, so the joint's axes pass through the annotated point. An offset towards the palm
(z) acts on the points as a constant shift of the flexion angles would (the flexion axes
are parallel along a finger); the angles stay within their limits. The prior holds each
offset at 0 with a standard deviation of ``PRIOR_OFFSET_MM`` (at scale 1), within
+-``OFFSET_MAX_MM``. Prior: the proportions above (Buchholz et al. 1992 for
the bones), for a free whole-hand scale, with a standard deviation of ``PRIOR_BONE_REL``
of each length and ``PRIOR_BASE_MM`` per base coordinate (at scale 1). A derived point
whose weights are a convex combination (all >= 0, sum 1) keeps them so: each weight of its
support (the palm joints and its own joints) lies in [0, 1] and they are normalised to sum
1; any other derived point is an offset from its largest-weight joint, each other weight
within +-``OFFSET_WEIGHT_MAX``.

Settings no human hand has are refused, one line naming the setting: ``scale`` 0.2 to 5;
bone lengths 1 to 200 mm (a hand's bones are millimetres to about 100 mm); each coordinate
of a base position within +-300 mm of the wrist and of a bone offset within +-50 mm; angle
limits within +-180 degrees, lower <= upper; derived-point weights within +-10 (all finite).
Calibration's hard limits lie inside these ranges.
"""

from __future__ import annotations


from typing import ClassVar

import numpy as np
from pydantic import Field, field_validator

from hybridfit.model.kinematics import NO_AXIS, X_AXIS, Z_AXIS, KinematicTree, TreeHandModel
from hybridfit.model.base import Geometry, Stage
from hybridfit.plugin import Settings

FINGERS = ("thumb", "index", "middle", "ring", "little")
FINGER_JOINTS = {
    "thumb": ("cmc", "mcp", "ip", "tip"),
    **{f: ("mcp", "pip", "dip", "tip") for f in FINGERS[1:]},
}
FINGER_ANGLES = {
    "thumb": ("cmc_flexion", "cmc_abduction", "mcp_flexion", "ip_flexion"),
    **{f: ("mcp_flexion", "mcp_abduction", "pip_flexion", "dip_flexion") for f in FINGERS[1:]},
}
#: per finger, the rotations of its three moving joints (base, second, third) in the order
#: applied: (axis in the joint's frame, angle name); the base joint abducts, then flexes
JOINT_AXES = {
    "thumb": (((Z_AXIS, "cmc_abduction"), (X_AXIS, "cmc_flexion")), ((X_AXIS, "mcp_flexion"),), ((X_AXIS, "ip_flexion"),)),
    **{f: (((Z_AXIS, "mcp_abduction"), (X_AXIS, "mcp_flexion")), ((X_AXIS, "pip_flexion"),), ((X_AXIS, "dip_flexion"),))
       for f in FINGERS[1:]},
}
SEGMENTS = {"thumb": ("metacarpal", "proximal", "distal"), **{f: ("proximal", "middle", "distal") for f in FINGERS[1:]}}

#: base joint positions relative to the wrist in the hand frame (mm, scale 1)
BASE_POSITIONS = {
    "thumb": (22.0, 22.0, 12.0),
    "index": (25.0, 80.0, 0.0),
    "middle": (6.0, 82.0, 0.0),
    "ring": (-12.0, 77.0, 0.0),
    "little": (-28.0, 70.0, 0.0),
}
#: segment lengths (mm, scale 1), base to tip
BONE_LENGTHS = {
    "thumb": (44.0, 32.0, 27.0),
    "index": (40.0, 24.0, 19.0),
    "middle": (45.0, 28.0, 20.0),
    "ring": (42.0, 27.0, 20.0),
    "little": (33.0, 20.0, 18.0),
}
#: rest direction of each finger's first segment in the hand frame, and its bending direction
REST_DIRECTIONS = {
    "thumb": ((0.65, 0.75, 0.10), (-0.55, 0.0, 0.85)),
    "index": ((0.12, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "middle": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "ring": ((-0.08, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "little": ((-0.20, 1.0, 0.0), (0.0, 0.0, 1.0)),
}
LIMITS_DEG = {
    "thumb": ((-20.0, 60.0), (-30.0, 40.0), (0.0, 80.0), (-20.0, 90.0)),
    **{f: ((0.0, 90.0), (-15.0, 15.0), (0.0, 110.0), (0.0, 90.0)) for f in FINGERS[1:]},
}
#: a relaxed hand: fingers slightly flexed (degrees)
DEFAULT_POSE_DEG = {
    "thumb": (5.0, 0.0, 5.0, 5.0),
    **{f: (10.0, 0.0, 10.0, 5.0) for f in FINGERS[1:]},
}

#: named hand shapes (degrees, per finger in FINGER_ANGLES order), the test sequence's key
#: poses (``named_poses_deg``): thumb states and finger states, combined below
_THUMB_STATES = {"open": (-12, -25, 5, 3), "rest": (8, 0, 12, 10), "across": (45, 35, 35, 25),
                 "pinch": (40, 10, 30, 25), "grasp": (25, 15, 20, 15)}
_FINGER_STATES = {"straight": (3, 0, 3, 2), "fist": (85, 0, 95, 65), "rest": (15, 0, 20, 10),
                  "half": (40, 0, 45, 25), "grasp": (50, 0, 55, 35), "pinch": (45, 0, 35, 20),
                  "wave": (60, 0, 70, 40)}
_SPREAD = (-10, -2, 6, 12)  # abduction of index .. little in an open hand


def _hand(thumb: str, *fingers: str, spread: bool = False) -> np.ndarray:
    """(20,) degrees in hand26's angle order: a thumb state and four finger states (index .. little)."""
    out = [_THUMB_STATES[thumb]]
    for i, f in enumerate(fingers):
        a = list(_FINGER_STATES[f])
        if spread and f == "straight":
            a[1] = _SPREAD[i]
        out.append(a)
    return np.array(out, float).ravel()


KEY_POSES_DEG = {
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
#: the training grid's articulations per finger (degrees, FINGER_ANGLES order): 4^5 hand shapes
GRID_ARTICULATIONS_DEG = {
    "thumb": [(-10, -20, 5, 0), (10, 0, 20, 15), (40, 30, 30, 20), (55, 20, 60, 60)],
    **{f: [(5, 0, 5, 5), (30, 0, 50, 30), (60, 0, 10, 5), (80, 0, 100, 70)] for f in FINGERS[1:]},
}

#: calibration prior: std of each bone length as a fraction of it, std of base coordinates (mm, scale 1)
PRIOR_BONE_REL = 0.2
PRIOR_BASE_MM = 10.0
#: calibration prior of a bone's offset across the bone: std and bound of each coordinate (mm, scale 1)
PRIOR_OFFSET_MM = 3.0
OFFSET_MAX_MM = 15.0
#: the bone offset's coordinates (x: along the flexion axis, z: palmar, in the bone's frame) and
#: those calibration may change
OFFSET_AXES = ("x", "z")
#: std of a derived point's weights in the prior; the bound of an offset point's weights
PRIOR_WEIGHT = 0.15
OFFSET_WEIGHT_MAX = 0.6
#: joints of the rigid palm: every derived point's weights may use them
PALM_JOINTS = ("wrist", "thumb_cmc", "index_mcp", "middle_mcp", "ring_mcp", "little_mcp")



def parameter_names(finger_angles: dict[str, tuple[str, ...]]) -> tuple[str, ...]:
    """The global pose's 7 parameter names, then each finger's angles in finger order."""
    return ("x", "y", "z", "qw", "qx", "qy", "qz") + tuple(f"{f}_{a}" for f in FINGERS for a in finger_angles[f])


PARAMETER_NAMES = parameter_names(FINGER_ANGLES)
JOINT_NAMES = ("wrist",) + tuple(f"{f}_{j}" for f in FINGERS for j in FINGER_JOINTS[f])
BONE_NAMES = tuple(f"{f}_{s}" for f in FINGERS for s in SEGMENTS[f])


#: plausible geometry settings, wider than any human hand (an adult's is about 190 mm long, its
#: bones millimetres to about 100 mm) and narrow enough to refuse nonsense: the whole-hand
#: scale; a bone's length (mm, before scaling); each coordinate of a finger's base position
#: relative to the wrist and of a bone's offset across the bone (mm, before scaling); an
#: angle's limits (degrees); the magnitude of a derived point's weights
SCALE_RANGE = (0.2, 5.0)
BONE_MM = (1.0, 200.0)
BASE_MAX_MM = 300.0
OFFSET_MAX_SETTING_MM = 50.0
LIMIT_MAX_DEG = 180.0
WEIGHT_MAX = 10.0


def _within(values, lo: float, hi: float) -> bool:
    """Whether every value is a number within [lo, hi] (NaN is not)."""
    return all(lo <= v <= hi for v in values)


def _known(names, known, kind: str) -> None:
    """Raise ValueError naming the first of ``names`` not in ``known`` (a settings check)."""
    for name in names:
        if name not in known:
            raise ValueError(f"unknown {kind} {name!r} ({kind}s: {', '.join(known)})")


class Hand26Settings(Settings):
    """Geometry of the hand26 model. Lengths in millimetres, angles in degrees."""

    #: the articulation angles whose limits ``limits_deg`` may override
    angle_names: ClassVar[tuple[str, ...]] = PARAMETER_NAMES[7:]

    scale: float = Field(1.0, description="global scale of every length, 0.2 to 5")
    bone_lengths: dict[str, float] = Field(
        default_factory=dict, description="per-bone length overrides in mm before scaling, 1 to 200, e.g. "
        "{'index_proximal': 42}"
    )
    base_positions: dict[str, tuple[float, float, float]] = Field(
        default_factory=dict, description="per-finger base joint position relative to the wrist (hand frame, mm, "
        "each coordinate within +-300)"
    )
    bone_offsets: dict[str, tuple[float, float]] = Field(
        default_factory=dict,
        description="per-bone offset (x, z) of its end joint across the bone in mm before scaling, in the bone's "
        "frame (x along the flexion axis, z palmar), e.g. {'thumb_distal': [1.5, -2]}; default 0, each within +-50",
    )
    limits_deg: dict[str, tuple[float, float]] = Field(
        default_factory=dict, description="per-angle limit overrides in degrees, within +-180, e.g. "
        "{'index_mcp_flexion': [-10, 90]}"
    )
    mirror: bool = Field(False, description="left hand (mirror image of the right hand)")
    derived_points: dict[str, dict[str, float]] = Field(
        default_factory=dict,
        description="extra named points as joint weights (each within +-10), e.g. {'icvl_palm': {'wrist': 0.5, "
        "'middle_mcp': 0.5}}; a name given here replaces a built-in derived point of that name",
    )

    @field_validator("scale")
    @classmethod
    def _scale(cls, v):
        if not _within([v], *SCALE_RANGE):
            raise ValueError(f"the scale must be {SCALE_RANGE[0]:g} to {SCALE_RANGE[1]:g} (times an average adult "
                             f"hand, about 190 mm long), got {v}")
        return v

    @field_validator("bone_lengths")
    @classmethod
    def _bones(cls, v):
        _known(v, BONE_NAMES, "bone")
        for name, length in v.items():
            if not _within([length], *BONE_MM):
                raise ValueError(f"bone {name!r} must be {BONE_MM[0]:g} to {BONE_MM[1]:g} mm long (a human hand's "
                                 f"bones are millimetres to about 100 mm), got {length}")
        return v

    @field_validator("bone_offsets")
    @classmethod
    def _offsets(cls, v):
        _known(v, BONE_NAMES, "bone")
        for name, offset in v.items():
            if not _within(offset, -OFFSET_MAX_SETTING_MM, OFFSET_MAX_SETTING_MM):
                raise ValueError(f"the offset of {name!r} must be finite, within +-{OFFSET_MAX_SETTING_MM:g} mm in "
                                 f"each coordinate, got {list(offset)}")
        return v

    @field_validator("base_positions")
    @classmethod
    def _bases(cls, v):
        _known(v, FINGERS, "finger")
        for name, position in v.items():
            if not _within(position, -BASE_MAX_MM, BASE_MAX_MM):
                raise ValueError(f"the base position of {name!r} must be finite, within +-{BASE_MAX_MM:g} mm of the "
                                 f"wrist in each coordinate (a hand is about 190 mm long), got {list(position)}")
        return v

    @field_validator("limits_deg")
    @classmethod
    def _limits(cls, v):
        _known(v, cls.angle_names, "angle")
        for name, (lo, hi) in v.items():
            if not (_within([lo, hi], -LIMIT_MAX_DEG, LIMIT_MAX_DEG) and lo <= hi):
                raise ValueError(f"the limits of {name!r} must be degrees within [-{LIMIT_MAX_DEG:g}, "
                                 f"{LIMIT_MAX_DEG:g}] with lower <= upper, got ({lo}, {hi})")
        return v

    @field_validator("derived_points")
    @classmethod
    def _derived(cls, v):
        for name, weights in v.items():
            if name in JOINT_NAMES:
                raise ValueError(f"derived point {name!r} has the name of a joint")
            if not weights:
                raise ValueError(f"derived point {name!r} has no joint weights")
            for joint, weight in weights.items():
                if joint not in JOINT_NAMES:
                    raise ValueError(f"derived point {name!r}: unknown joint {joint!r} (joints: {', '.join(JOINT_NAMES)})")
                if not _within([weight], -WEIGHT_MAX, WEIGHT_MAX):
                    raise ValueError(f"derived point {name!r}: the weight of {joint!r} must be finite, within "
                                     f"+-{WEIGHT_MAX:g}, got {weight}")
        return v


def _frame(direction, bend) -> np.ndarray:
    """Finger rest frame: columns x (flexion axis), y (along the bone), z (bending side)."""
    y = np.asarray(direction, float)
    y /= np.linalg.norm(y)
    z = np.asarray(bend, float) - np.dot(bend, y) * y
    z /= np.linalg.norm(z)
    return np.stack([np.cross(y, z), y, z], axis=1)


_REST_FRAMES = {f: _frame(*REST_DIRECTIONS[f]) for f in FINGERS}


class Hand26(TreeHandModel):
    """The paper's 26-DoF (27-parameter) joints-only hand model with anatomical limits.

    The per-finger tables below are class attributes so that a richer model (``hand27``)
    changes a finger's joints and angles and inherits everything else."""

    Settings = Hand26Settings
    parameter_names = PARAMETER_NAMES
    joint_names = JOINT_NAMES
    bone_names = BONE_NAMES
    mirror_setting = "mirror"
    derived_points_setting = "derived_points"
    #: per finger: its angle names in parameter order, the rotations of its three moving
    #: joints, the angles' limits and default pose (degrees, in the angles' order)
    finger_angles: ClassVar[dict[str, tuple[str, ...]]] = FINGER_ANGLES
    joint_axes: ClassVar[dict[str, tuple]] = JOINT_AXES
    angle_limits_deg: ClassVar[dict[str, tuple[tuple[float, float], ...]]] = LIMITS_DEG
    default_pose_deg: ClassVar[dict[str, tuple[float, ...]]] = DEFAULT_POSE_DEG
    #: each finger's (3, 3) rest frame of its base joint in the hand frame
    rest_frames: ClassVar[dict[str, np.ndarray]] = _REST_FRAMES
    #: the bone offsets' coordinates that are calibratable geometry (of OFFSET_AXES)
    calibrated_offset_axes: ClassVar[tuple[str, ...]] = OFFSET_AXES

    def kinematic_tree(self) -> KinematicTree:
        """Wrist (root) -> each finger's base joint -> two further joints -> tip."""
        s = self.settings
        bases = np.array([s.base_positions.get(f, BASE_POSITIONS[f]) for f in FINGERS], float) * s.scale
        lengths = self._lengths()
        centre = bases[1:].sum(axis=0) / 5.0  # palm_centre (mean of the wrist at 0 and 4 MCPs) is the origin
        index = {name: i for i, name in enumerate(self.parameter_names)}
        J = len(JOINT_NAMES)
        parents = np.zeros(J, dtype=np.int64)
        offsets = np.zeros((J, 3))
        rest = np.tile(np.eye(3), (J, 1, 1))
        axes = np.full((J, 2), NO_AXIS, dtype=np.int64)
        axis_params = np.zeros((J, 2), dtype=np.int64)
        parents[0], offsets[0] = -1, -centre
        for f, finger in enumerate(FINGERS):
            base = 1 + 4 * f
            parents[base], offsets[base], rest[base] = 0, bases[f], self.rest_frames[finger]
            for k in range(3):
                j = base + 1 + k
                across = s.scale * np.asarray(s.bone_offsets.get(f"{finger}_{SEGMENTS[finger][k]}", (0.0, 0.0)), float)
                parents[j], offsets[j] = j - 1, (across[0], lengths[f, k], across[1])
            for k, rotations in enumerate(self.joint_axes[finger]):
                for a, (axis, angle) in enumerate(rotations):
                    axes[base + k, a], axis_params[base + k, a] = axis, index[f"{finger}_{angle}"]
        return KinematicTree(parents, offsets, rest, axes, axis_params, -1.0 if s.mirror else 1.0)

    def _lengths(self) -> np.ndarray:
        """(5, 3) segment lengths in mm, scale applied."""
        s = self.settings
        return s.scale * np.array(
            [[s.bone_lengths.get(f"{f}_{seg}", L) for seg, L in zip(SEGMENTS[f], BONE_LENGTHS[f])] for f in FINGERS]
        )

    @property
    def derived_points(self):
        """``palm_centre`` (mean of the wrist and the four finger MCPs) and the settings' points."""
        builtin = {"palm_centre": {j: 0.2 for j in ("wrist", "index_mcp", "middle_mcp", "ring_mcp", "little_mcp")}}
        return {**builtin, **self.settings.derived_points}

    def bone_lengths(self) -> dict[str, float]:
        """Each bone's length in mm (scale applied), by bone name: along the bone's rest
        direction (its offset, if any, lies across it)."""
        lengths = self._lengths()
        return {f"{f}_{seg}": float(lengths[i, k]) for i, f in enumerate(FINGERS) for k, seg in enumerate(SEGMENTS[f])}

    def geometry(self) -> Geometry:
        """Bone lengths and base positions (mm, scale applied) and the settings' derived-point
        weights, with the Buchholz et al. (1992) proportions as the prior (see the module doc)."""
        s = self.settings
        names, values, mean, std, lower, upper, scaled, ends = [], [], [], [], [], [], [], []

        def add(name, value, mu, sd, lo, hi, is_length, end):
            names.append(name), values.append(value), mean.append(mu), std.append(sd)
            lower.append(lo), upper.append(hi), scaled.append(is_length), ends.append(end)

        lengths = self.bone_lengths()
        for f in FINGERS:
            chain = [f"{f}_{j}" for j in FINGER_JOINTS[f]]
            for k, seg in enumerate(SEGMENTS[f]):
                mu = BONE_LENGTHS[f][k]
                add(f"{f}_{seg}", lengths[f"{f}_{seg}"], mu, PRIOR_BONE_REL * mu, 0.3 * mu, 3.0 * mu, True,
                    (chain[k], chain[k + 1]))
        for f in FINGERS:
            base = np.array(s.base_positions.get(f, BASE_POSITIONS[f]), float) * s.scale
            for c, axis in enumerate("xyz"):
                mu = BASE_POSITIONS[f][c]
                add(f"{f}_base_{axis}", base[c], mu, PRIOR_BASE_MM, mu - 150.0, mu + 150.0, True,
                    ("wrist", f"{f}_{FINGER_JOINTS[f][0]}"))
        for f in FINGERS:
            chain = [f"{f}_{j}" for j in FINGER_JOINTS[f]]
            for k, seg in enumerate(SEGMENTS[f]):
                across = s.scale * np.asarray(s.bone_offsets.get(f"{f}_{seg}", (0.0, 0.0)), float)
                for axis in self.calibrated_offset_axes:
                    c = OFFSET_AXES.index(axis)
                    add(f"{f}_{seg}_offset_{axis}", across[c], 0.0, PRIOR_OFFSET_MM, -OFFSET_MAX_MM, OFFSET_MAX_MM,
                        True, (chain[k], chain[k + 1]))
        for point, weights in s.derived_points.items():
            support, anchor = _weight_support(weights)
            convex = anchor is None
            for j in support:
                w = weights.get(j, 0.0)
                lo, hi = (0.0, 1.0) if convex else (-OFFSET_WEIGHT_MAX, OFFSET_WEIGHT_MAX)
                add(f"{point}.{j}", w, w, PRIOR_WEIGHT, lo, hi, False, (point, j))
        f64 = lambda v: np.asarray(v, dtype=np.float64)  # noqa: E731
        return Geometry(tuple(names), f64(values), f64(mean), f64(std), f64(lower), f64(upper),
                        np.asarray(scaled, dtype=bool), tuple(ends))

    def with_geometry(self, values) -> dict:
        """These settings with geometry ``values`` (the order of ``geometry().names``): scale 1,
        explicit bone lengths and base positions, convex weights normalised to sum 1."""
        values = np.asarray(values, dtype=np.float64)
        s = self.settings
        out = self.get_params()
        out["scale"] = 1.0
        out["bone_lengths"] = {b: float(v) for b, v in zip(BONE_NAMES, values[:15])}
        out["base_positions"] = {f: [float(c) for c in values[15 + 3 * i: 18 + 3 * i]] for i, f in enumerate(FINGERS)}
        axes = [OFFSET_AXES.index(a) for a in self.calibrated_offset_axes]
        k = 30 + len(BONE_NAMES) * len(axes)
        offsets = {b: np.array(s.bone_offsets.get(b, (0.0, 0.0)), float) * s.scale for b in BONE_NAMES}
        for i, b in enumerate(BONE_NAMES):
            offsets[b][axes] = values[30 + len(axes) * i: 30 + len(axes) * (i + 1)]
        out["bone_offsets"] = {b: [float(c) for c in v] for b, v in offsets.items() if v.any()}
        derived = {}
        for point, weights in s.derived_points.items():
            support, anchor = _weight_support(weights)
            w = dict(zip(support, values[k: k + len(support)]))
            k += len(support)
            if anchor is None:
                total = sum(w.values())
                w = {j: v / total for j, v in w.items()} if total > 0 else dict(weights)
            else:
                w[anchor] = sum(weights.values()) - sum(w.values())
            derived[point] = {j: float(v) for j, v in w.items() if v != 0.0}
        out["derived_points"] = derived
        if k != len(values):
            raise ValueError(f"hand26 geometry has {k} entries, got {len(values)} values")
        return out

    def bounds(self):
        P = self.n_params
        lower = np.full(P, -np.inf)
        upper = np.full(P, np.inf)
        lower[3:7], upper[3:7] = -1.0, 1.0
        table = {f"{f}_{a}": lim for f in FINGERS for a, lim in zip(self.finger_angles[f], self.angle_limits_deg[f])}
        for i, name in enumerate(self.parameter_names[7:], start=7):
            lo, hi = self.settings.limits_deg.get(name, table[name])
            lower[i], upper[i] = np.radians(lo), np.radians(hi)
        return lower, upper

    def default_params(self):
        x = np.zeros(self.n_params)
        x[3] = 1.0
        x[7:] = np.radians([a for f in FINGERS for a in self.default_pose_deg[f]])
        lower, upper = self.bounds()
        return np.clip(x, lower, upper)

    def named_poses_deg(self) -> dict[str, np.ndarray]:
        """The test sequence's key poses (open, rest, fist, counting, pinch, grasp, ok, finger
        waves): {name: (P - 7,) articulation angles in degrees}; an angle hand26 lacks is 0."""
        hand26 = PARAMETER_NAMES[7:]
        return {name: np.array([dict(zip(hand26, pose)).get(a, 0.0) for a in self.parameter_names[7:]])
                for name, pose in KEY_POSES_DEG.items()}

    def grid_articulations_deg(self) -> dict[str, list[tuple[float, ...]]]:
        """The training grid's articulations: {finger stage: [(its angles in degrees), ...]};
        an angle hand26 lacks is 0."""
        return {f: [tuple(dict(zip(FINGER_ANGLES[f], art)).get(a, 0.0) for a in self.finger_angles[f])
                    for art in GRID_ARTICULATIONS_DEG[f]] for f in FINGERS}

    def stages(self):
        palm = Stage("palm", tuple(range(7)), (0,) + tuple(1 + 4 * f for f in range(5)))
        fingers, first = [], 7
        for i, f in enumerate(FINGERS):
            n = len(self.finger_angles[f])
            fingers.append(Stage(f, tuple(range(first, first + n)), tuple(range(2 + 4 * i, 5 + 4 * i))))
            first += n
        return (palm, *fingers)


def _weight_support(weights: dict[str, float]) -> tuple[tuple[str, ...], str | None]:
    """The joints whose weights calibration may change for a derived point, and its anchor:
    None for a convex combination (all weights >= 0, sum 1), else the largest-weight joint
    (its weight keeps the sum and is not in the support)."""
    joints = tuple(dict.fromkeys((*PALM_JOINTS, *weights)))
    if min(weights.values()) >= 0 and abs(sum(weights.values()) - 1.0) < 1e-6:
        return joints, None
    anchor = max(weights, key=lambda j: weights[j])
    return tuple(j for j in joints if j != anchor), anchor
