"""``hand29``: hand27 with a palm arch, 29 DoF (30 parameters, 23 joints).

The 4th and 5th carpometacarpal (CMC) joints flex: the ring and little metacarpals turn
towards the palm and arch it (cupping, as in a power grip). The index and middle CMCs stay
rigid, as in hand26 and hand27. Everything else is hand27's (angles, bones, base positions,
rest frames, calibratable geometry, derived points, settings), and a hand29 pose with both
arch angles 0 is the hand27 pose with the same other angles (to rounding: within 1e-12 mm).

Parameters (30): hand27's 28 (the first 28 are a hand27 pose), then ``ring_cmc_flexion``
and ``little_cmc_flexion`` (radians, flexion towards the palm positive). They belong to the
palm stage, with the global pose.

Joints (23): the wrist, ``ring_cmc``, ``little_cmc``, then hand27's other 20 joints in
hand27's order. A CMC joint is a child of the wrist; it rotates about its metacarpal's
flexion axis: through the joint, perpendicular to the wrist-to-MCP line within the palm
plane (the hand frame's x, tilted with the metacarpal). Its finger's MCP (and so the whole
finger) is its child. The palm stage owns the wrist, the two CMCs and the five finger bases.

Where the CMCs are: on the line from the wrist to their finger's MCP, a fixed share of the
way (``CMC_SHARE``: ring 0.26, little 0.29), so that the MCP is one metacarpal length from
its CMC at the default base positions: mean radiographic metacarpal lengths, ring 58.0 mm
and little 53.7 mm (Buryanov & Kotiuk, "Proportions of hand segments", Int. J. Morphol.
28(3):755-758, 2010). The CMCs then sit 19.9 mm (ring) and 21.7 mm (little) from the
wrist. The flexion axes lie in the bases of the metacarpals (El-Shennawy, Nakamura,
Patterson & Viegas, "Three-dimensional kinematic analysis of the second through fifth
carpometacarpal joints", J Hand Surg Am 26(6):1030-1035, 2001). A CMC is not calibrated
geometry of its own: it moves with its finger's calibrated base position, at the same share.

Anatomical limits (degrees), after El-Shennawy et al. (2001; cadavers): the flexion-extension
arcs of the CMCs are 11 (index), 7 (middle), 20 (ring) and 27 (little); the 5th CMC's arc
drops by 40% when the 4th is immobilised (the two are coupled; we do not model this).
Batmanabane & Malathi, "Movements at the carpometacarpal and metacarpophalangeal joints of
the hand and their effect on the dimensions of the articular ends of the metacarpal bones",
Anat. Rec. 213:102-110, 1985, rank CMC mobility 1 > 5 > 4 > 2 > 3. hand26's palm is flat
(the four finger MCPs coplanar), its flattest shape, so we count each whole arc as flexion
from it: ``ring_cmc_flexion`` 0..20, ``little_cmc_flexion`` 0..27. Default pose: 0 (flat).

Not modelled: the CMCs' radial-ulnar deviation and pronation-supination (El-Shennawy et al.:
up to 13 and 22 degrees at the 5th CMC), the obliquity of their axes, and the index and
middle CMCs. The hand frame's origin is the palm centre of the flat palm; with the palm
arched, ``palm_centre`` (a derived point) moves with the ring and little MCPs. Derived
points in the settings combine hand27's joints (the CMCs are not among their choices).
"""

from __future__ import annotations

from functools import cached_property
from typing import ClassVar

import numpy as np

from hybridfit.model.base import Stage
from hybridfit.model.kinematics import NO_AXIS, X_AXIS, KinematicTree

from .hand26 import BASE_POSITIONS, JOINT_NAMES, _frame
from .hand27 import PARAMETER_NAMES_27, Hand27, Hand27Settings

#: the arched fingers, their CMC joints and arch angles (in parameter order)
ARCH_FINGERS = ("ring", "little")
CMC_JOINTS = tuple(f"{f}_cmc" for f in ARCH_FINGERS)
ARCH_ANGLES = tuple(f"{f}_cmc_flexion" for f in ARCH_FINGERS)
ARCH_LIMITS_DEG = {"ring_cmc_flexion": (0.0, 20.0), "little_cmc_flexion": (0.0, 27.0)}
ARCH_DEFAULT_DEG = {"ring_cmc_flexion": 0.0, "little_cmc_flexion": 0.0}
#: metacarpal lengths (mm, scale 1; Buryanov & Kotiuk 2010) and the share of the wrist-to-MCP
#: line at which the CMC sits, so that the default MCP is one metacarpal length from it
METACARPAL_MM = {"ring": 58.0, "little": 53.7}
CMC_SHARE = {f: 1.0 - METACARPAL_MM[f] / float(np.linalg.norm(BASE_POSITIONS[f])) for f in ARCH_FINGERS}

PARAMETER_NAMES_29 = PARAMETER_NAMES_27 + ARCH_ANGLES
JOINT_NAMES_29 = ("wrist",) + CMC_JOINTS + JOINT_NAMES[1:]
#: hand27's joint j is joint HAND27_JOINT[j] here (the CMCs come right after the wrist)
HAND27_JOINT = np.r_[0, np.arange(3, len(JOINT_NAMES_29))]


class Hand29Settings(Hand27Settings):
    """Geometry of the hand29 model (hand27's settings). Lengths in mm, angles in degrees."""

    angle_names: ClassVar[tuple[str, ...]] = PARAMETER_NAMES_29[7:]


class Hand29(Hand27):
    """hand27 with ring and little CMC flexion (the palm arch): 29 DoF, 30 parameters."""

    Settings = Hand29Settings
    parameter_names = PARAMETER_NAMES_29
    joint_names = JOINT_NAMES_29

    @cached_property
    def _hand27(self) -> Hand27:
        """The hand27 of these settings: hand29's first 28 parameters are its pose."""
        limits = {name: lim for name, lim in self.settings.limits_deg.items() if name in PARAMETER_NAMES_27}
        return Hand27(**{**self.get_params(), "limits_deg": limits})

    def kinematic_tree(self) -> KinematicTree:
        """hand27's tree with a CMC joint between the wrist and the ring and little MCPs; at
        zero flexion every hand27 joint is where hand27 puts it."""
        t = super().kinematic_tree()  # hand27's 21 joints (its angles have the same indices here)
        J = len(JOINT_NAMES_29)
        parents = np.zeros(J, dtype=np.int64)
        offsets, rest = np.zeros((J, 3)), np.tile(np.eye(3), (J, 1, 1))
        axes = np.full((J, t.axes.shape[1]), NO_AXIS, dtype=np.int64)
        axis_params = np.zeros_like(axes)
        parents[HAND27_JOINT] = HAND27_JOINT[np.maximum(t.parents, 0)]
        parents[0] = -1
        offsets[HAND27_JOINT], rest[HAND27_JOINT] = t.offsets, t.rest
        axes[HAND27_JOINT], axis_params[HAND27_JOINT] = t.axes, t.axis_params
        for finger, cmc, angle in zip(ARCH_FINGERS, CMC_JOINTS, ARCH_ANGLES):
            c, mcp = JOINT_NAMES_29.index(cmc), JOINT_NAMES_29.index(f"{finger}_mcp")
            base = t.offsets[JOINT_NAMES.index(f"{finger}_mcp")]  # the MCP from the wrist, hand frame
            at = CMC_SHARE[finger] * base
            # x: the flexion axis, y: along the metacarpal, z: palmar (a tuple: _frame normalises an array in place)
            frame = _frame(tuple(base), (0.0, 0.0, 1.0))
            parents[c], offsets[c], rest[c] = 0, at, frame
            axes[c, 0], axis_params[c, 0] = X_AXIS, self.parameter_names.index(angle)
            parents[mcp], offsets[mcp], rest[mcp] = c, frame.T @ (base - at), frame.T @ rest[mcp]
        return KinematicTree(parents, offsets, rest, axes, axis_params, t.mirror)

    def bounds(self):
        """hand27's bounds, then the arch angles' (radians; ``limits_deg`` may override them)."""
        lower, upper = self._hand27.bounds()
        arch = np.radians([self.settings.limits_deg.get(a, ARCH_LIMITS_DEG[a]) for a in ARCH_ANGLES])  # (2, 2)
        return np.r_[lower, arch[:, 0]], np.r_[upper, arch[:, 1]]

    def default_params(self):
        """hand27's default pose with the default arch (flat), within the bounds."""
        return self.clip(np.r_[self._hand27.default_params(), np.radians([ARCH_DEFAULT_DEG[a] for a in ARCH_ANGLES])])

    def stages(self):
        """hand27's stages on hand29's joints; the palm stage also holds the arch angles and
        the CMC joints."""
        palm, *fingers = super().stages()
        ours = lambda joints: tuple(int(HAND27_JOINT[j]) for j in joints)  # noqa: E731
        arch = tuple(self.parameter_names.index(a) for a in ARCH_ANGLES)
        cmcs = tuple(JOINT_NAMES_29.index(c) for c in CMC_JOINTS)
        palm = Stage(palm.name, palm.parameters + arch, ours(palm.joints[:1]) + cmcs + ours(palm.joints[1:]))
        return (palm, *(Stage(s.name, s.parameters, ours(s.joints)) for s in fingers))
