"""``hand27``: hand26 with a richer thumb, 27 DoF (28 parameters, 21 joints).

The thumb's MCP joint gets a second degree of freedom, abduction/adduction, beside its
flexion, as the finger MCPs have: CMC 2 DoF (flexion, abduction), MCP 2 DoF (flexion,
abduction), IP 1 DoF. Everything else is hand26's (joints, joint names, bones, base
positions, rest frames, calibratable geometry, derived points, settings), so every skeleton
file that maps onto hand26 maps onto hand27, and a hand27 pose with
``thumb_mcp_abduction = 0`` is the hand26 pose with the same other angles.

Parameters (28): hand26's, with the thumb's five angles in the order ``thumb_cmc_flexion,
thumb_cmc_abduction, thumb_mcp_flexion, thumb_mcp_abduction, thumb_ip_flexion`` (radians).
The MCP rotates first about the proximal phalanx's palmar axis (z, abduction), then about
its flexion axis (x), as the finger MCPs do; positive abduction turns the phalanx in the
same sense as positive CMC abduction.

Anatomical limits (degrees):
- CMC flexion -20..60 and abduction -30..40, MCP flexion 0..80 and IP -20..90: as hand26
  (AAOS, Greene & Heckman, "The clinical measurement of joint motion", 1994), kept so that
  the two models differ only by the new degree of freedom. They cover the normal ranges
  measured since: Barakat, Field & Taylor, "The range of movement of the thumb", Hand
  8(2):179-182, 2013 (100 hands: MCP flexion 60, range 43-70, extension 8; IP flexion 88,
  range 80-90, extension 12; CMC radial abduction 63, anteposition 61), and Hume, Gellman,
  McKellop & Brumfield, "Functional range of motion of the joints of the hand", J Hand Surg
  15A(2):240-243, 1990 (functional thumb MCP flexion averages 21, IP 18, 32% of the
  available flexion; active MCP flexion is bimodal across people).
- MCP abduction/adduction -15..15. The thumb MCP is a condyloid joint whose abduction is
  small and closely coupled to the other thumb joints (Jarque-Bou, Vergara & Sancho-Bru,
  "Estimation of the abduction/adduction movement of the metacarpophalangeal joint of the
  thumb", Appl. Sci. 11(7):3158, 2021; Kapandji, "The physiology of the joints", vol. 1).
  None of these sources gives one active range for it that we could adopt: +-15 is our
  choice, the range Lin, Wu & Huang (2000) give the finger MCPs.

The thumb's rest frame and CMC axes are hand26's. The CMC is a saddle joint whose two axes
are neither orthogonal nor intersecting (Hollister, Buford, Myers, Giurintano & Novick,
"The axes of rotation of the thumb carpometacarpal joint", J Orthop Res 10:454-460,
1992), which neither model represents; we did not change them here, so that the
comparison with hand26 isolates the new MCP degree of freedom.
"""

from __future__ import annotations

from typing import ClassVar

from .hand26 import (DEFAULT_POSE_DEG, FINGER_ANGLES, JOINT_AXES, LIMITS_DEG, X_AXIS, Z_AXIS, Hand26,
                     Hand26Settings, parameter_names)

FINGER_ANGLES_27 = {
    **FINGER_ANGLES,
    "thumb": ("cmc_flexion", "cmc_abduction", "mcp_flexion", "mcp_abduction", "ip_flexion"),
}
JOINT_AXES_27 = {
    **JOINT_AXES,
    "thumb": (JOINT_AXES["thumb"][0], ((Z_AXIS, "mcp_abduction"), (X_AXIS, "mcp_flexion")), JOINT_AXES["thumb"][2]),
}
LIMITS_DEG_27 = {**LIMITS_DEG, "thumb": ((-20.0, 60.0), (-30.0, 40.0), (0.0, 80.0), (-15.0, 15.0), (-20.0, 90.0))}
DEFAULT_POSE_DEG_27 = {**DEFAULT_POSE_DEG, "thumb": (5.0, 0.0, 5.0, 0.0, 5.0)}
PARAMETER_NAMES_27 = parameter_names(FINGER_ANGLES_27)


class Hand27Settings(Hand26Settings):
    """Geometry of the hand27 model (hand26's settings). Lengths in mm, angles in degrees."""

    angle_names: ClassVar[tuple[str, ...]] = PARAMETER_NAMES_27[7:]


class Hand27(Hand26):
    """hand26 with a 2-DoF thumb MCP (flexion and abduction): 27 DoF, 28 parameters."""

    Settings = Hand27Settings
    parameter_names = PARAMETER_NAMES_27
    finger_angles = FINGER_ANGLES_27
    joint_axes = JOINT_AXES_27
    angle_limits_deg = LIMITS_DEG_27
    default_pose_deg = DEFAULT_POSE_DEG_27
