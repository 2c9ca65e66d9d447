"""Each dataset's camera and xyz convention: camera coordinates <-> the dataset's own xyz.

Inside hybridfit every point is in camera coordinates: x right, y down, z forward (along
the optical axis, z = depth d), millimetres; u, v are pixels (u right, v down) in the depth
image and d the depth in mm. A dataset's own xyz convention appears only at the edges: its
reader converts the annotations in (:meth:`Convention.to_camera`) and an exporter writes
them back out (:meth:`Convention.from_camera`); both only flip signs, so a round trip is exact.

| dataset | image | fx, fy, cx, cy | its own xyz convention | hand in camera coordinates |
| --- | --- | --- | --- | --- |
| icvl | 320x240, 16-bit PNG, mm | 240.99, 240.96, 160, 120 | back-projected: x right, y down, z = d (= camera) | calibration decides (``mirror``) |
| nyu | 640x480, depth = G*256 + B in mm | 588.03, 587.07, 320, 240 | ``joint_xyz``: x right, y up, z = d | as recorded (its y-up xyz is a mirror image) |
| msra | 320x240, float32 box in a .bin, mm | 241.42, 241.42, 160, 120 | ``joint.txt``: x right, y up, z = -d | as recorded (y and z both flipped: a rotation) |
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import Intrinsics, uvd_to_xyz, xyz_to_uvd


@dataclass(frozen=True)
class Convention:
    """intrinsics; y_sign, z_sign: the dataset's xyz = (x, y_sign * y, z_sign * z) of camera x, y, z."""

    intrinsics: Intrinsics
    y_sign: float = 1.0
    z_sign: float = 1.0

    def _signs(self) -> np.ndarray:
        return np.array([1.0, self.y_sign, self.z_sign])

    def to_camera(self, xyz: np.ndarray) -> np.ndarray:
        """(..., 3) xyz (mm) in the dataset's convention -> (..., 3) camera coordinates (mm); exact."""
        return np.asarray(xyz, dtype=np.float64) * self._signs()

    def from_camera(self, xyz: np.ndarray) -> np.ndarray:
        """(..., 3) camera coordinates (mm) -> (..., 3) xyz (mm) in the dataset's convention; exact."""
        return np.asarray(xyz, dtype=np.float64) * self._signs()

    def uvd_to_camera(self, uvd: np.ndarray) -> np.ndarray:
        """(..., 3) u, v (px), d (mm) -> (..., 3) camera coordinates (mm)."""
        return uvd_to_xyz(uvd, self.intrinsics)

    def camera_to_uvd(self, xyz: np.ndarray) -> np.ndarray:
        """(..., 3) camera coordinates (mm) -> (..., 3) u, v (px), d (mm)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return xyz_to_uvd(xyz, self.intrinsics)

    def to_xyz(self, uvd: np.ndarray) -> np.ndarray:
        """(..., 3) u, v (px), d (mm) -> (..., 3) xyz (mm) in the dataset's own convention."""
        return self.from_camera(self.uvd_to_camera(uvd))

    def to_uvd(self, xyz: np.ndarray) -> np.ndarray:
        """(..., 3) xyz (mm) in the dataset's own convention -> (..., 3) u, v (px), d (mm)."""
        return self.camera_to_uvd(self.to_camera(xyz))


CONVENTIONS: dict[str, Convention] = {
    "icvl": Convention(Intrinsics(fx=240.99, fy=240.96, cx=160.0, cy=120.0, width=320, height=240)),
    "nyu": Convention(Intrinsics(fx=588.03, fy=587.07, cx=320.0, cy=240.0, width=640, height=480), y_sign=-1.0),
    "msra": Convention(Intrinsics(fx=241.42, fy=241.42, cx=160.0, cy=120.0, width=320, height=240),
                       y_sign=-1.0, z_sign=-1.0),
}
