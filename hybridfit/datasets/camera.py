"""Pinhole camera: intrinsics and uvd <-> xyz conversion, shared by every data path.

Camera coordinates: x right, y down, z along the optical axis (depth), millimetres; u, v
pixels (u right, v down), d = z in mm. Datasets whose own xyz convention differs (y up, for
example) are converted at the edges by :mod:`hybridfit.datasets.conventions`.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator


class Intrinsics(BaseModel):
    """Pinhole intrinsics in pixels and the image size. Default: the ICVL sensor."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    fx: float = Field(241.42, gt=0, description="focal length x, pixels")
    fy: float = Field(241.42, gt=0, description="focal length y, pixels")
    cx: float = Field(160.0, description="principal point x, pixels")
    cy: float = Field(120.0, description="principal point y, pixels")
    width: int = Field(320, gt=0, description="image width, pixels")
    height: int = Field(240, gt=0, description="image height, pixels")

    @model_validator(mode="after")
    def _centre_inside(self):
        if not (0 <= self.cx <= self.width and 0 <= self.cy <= self.height):
            raise ValueError(
                f"principal point ({self.cx}, {self.cy}) lies outside the {self.width}x{self.height} image"
            )
        return self

    def as_array(self) -> np.ndarray:
        """(4,) fx, fy, cx, cy."""
        return np.array([self.fx, self.fy, self.cx, self.cy])


def uvd_to_xyz(uvd: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """(..., 3) pixel u, v and depth d (mm) -> (..., 3) camera x, y, z (mm)."""
    uvd = np.asarray(uvd, dtype=np.float64)
    d = uvd[..., 2]
    x = (uvd[..., 0] - intrinsics.cx) * d / intrinsics.fx
    y = (uvd[..., 1] - intrinsics.cy) * d / intrinsics.fy
    return np.stack([x, y, d], axis=-1)


def xyz_to_uvd(xyz: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """(..., 3) camera x, y, z (mm) -> (..., 3) pixel u, v and depth d (mm)."""
    xyz = np.asarray(xyz, dtype=np.float64)
    z = xyz[..., 2]
    u = xyz[..., 0] * intrinsics.fx / z + intrinsics.cx
    v = xyz[..., 1] * intrinsics.fy / z + intrinsics.cy
    return np.stack([u, v, z], axis=-1)
