"""Each dataset's camera and xyz convention, and uvd <-> xyz in that convention.

Every dataset keeps its own xyz frame (millimetres); u, v are pixels (u right, v down) in
its depth image and d the depth in mm.

| dataset | image | fx, fy, cx, cy | xyz convention | hand in that frame |
| --- | --- | --- | --- | --- |
| icvl | 320x240, 16-bit PNG, mm | 240.99, 240.96, 160, 120 | back-projected: x right, y down, z = d | calibration decides (``mirror``) |
| nyu | 640x480, depth = G*256 + B in mm | 588.03, 587.07, 320, 240 | ``joint_xyz``: x right, y up, z = d | mirrored (a left-handed frame): ``mirror = true`` |
| msra | 320x240, float32 box in a .bin, mm | 241.42, 241.42, 160, 120 | ``joint.txt``: x right, y up, z = -d | right hand (y and z both flipped is a rotation) |
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Intrinsics


@dataclass(frozen=True)
class Convention:
    """intrinsics; y_sign, z_sign: xyz = (x, y_sign * y, z_sign * z) of the y-down camera frame."""

    intrinsics: Intrinsics
    y_sign: float = 1.0
    z_sign: float = 1.0

    def to_xyz(self, uvd: np.ndarray) -> np.ndarray:
        """(..., 3) u, v (px), d (mm) -> (..., 3) xyz (mm) in the dataset's frame."""
        uvd = np.asarray(uvd, dtype=np.float64)
        k, d = self.intrinsics, uvd[..., 2]
        x = (uvd[..., 0] - k.cx) * d / k.fx
        y = (uvd[..., 1] - k.cy) * d / k.fy
        return np.stack([x, self.y_sign * y, self.z_sign * d], axis=-1)

    def to_uvd(self, xyz: np.ndarray) -> np.ndarray:
        """(..., 3) xyz (mm) in the dataset's frame -> (..., 3) u, v (px), d (mm)."""
        xyz = np.asarray(xyz, dtype=np.float64)
        k, d = self.intrinsics, self.z_sign * xyz[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = xyz[..., 0] * k.fx / d + k.cx
            v = self.y_sign * xyz[..., 1] * k.fy / d + k.cy
        return np.stack([u, v, d], axis=-1)


CONVENTIONS: dict[str, Convention] = {
    "icvl": Convention(Intrinsics(fx=240.99, fy=240.96, cx=160.0, cy=120.0, width=320, height=240)),
    "nyu": Convention(Intrinsics(fx=588.03, fy=587.07, cx=320.0, cy=240.0, width=640, height=480), y_sign=-1.0),
    "msra": Convention(Intrinsics(fx=241.42, fy=241.42, cx=160.0, cy=120.0, width=320, height=240),
                       y_sign=-1.0, z_sign=-1.0),
}

