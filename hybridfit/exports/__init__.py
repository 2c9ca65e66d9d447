"""Standard exports of fits files (``hybridfit export``, ``hybridfit view``).

:func:`export` writes a fits file (``hybridfit fit --out``) in the format its output's
extension names:

- ``.json``: per frame the named joints (mm) and angles (degrees), with the model and its
  settings (:mod:`.tojson`);
- ``.bvh``: the model's skeleton and each frame's rotations, whose kinematics give the
  fitted joints (:mod:`.bvh`);
- ``.glb`` / ``.gltf``: glTF 2.0, the model's surface skinned to its skeleton and a keyframe
  per frame, whose joint nodes give the fitted joints (:mod:`.gltf`);
- ``.csv``: the joint-angle table of ``hybridfit export-angles``
  (:func:`hybridfit.fitting.angles.export_angles`, the same function).

:func:`hybridfit.exports.viewer.write_view` writes the 3D page of ``hybridfit view``. The
``.json``, ``.bvh``, glTF and page exports read the model from the fits file
(:mod:`.fitted`); a file written before fits named their model is refused, saying to re-run
``hybridfit fit``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import HybridfitError
from ..io import check_output

#: the formats :func:`export` writes, by extension
FORMATS = {".json": "JSON", ".bvh": "BVH", ".glb": "GLB", ".gltf": "glTF", ".csv": "CSV"}


@dataclass(frozen=True)
class Exported:
    """What :func:`export` wrote: format ("JSON", "BVH", "GLB", "glTF", "CSV"); frames: how many;
    failed: the rows of the frames that could not be fitted (in a BVH or glTF they hold the
    previous pose)."""

    format: str
    frames: int
    failed: tuple[int, ...]


def export_format(out: str | os.PathLike) -> str:
    """The format named by ``out``'s extension; a HybridfitError naming the known ones otherwise."""
    ext = Path(out).suffix.lower()
    if ext not in FORMATS:
        raise HybridfitError(f"{out}: cannot tell the export format from "
                             f"{repr(ext) if ext else 'a name without an extension'}; "
                             f"use {', '.join(FORMATS)}")
    return FORMATS[ext]


def export(fits: str | os.PathLike, out: str | os.PathLike, *, model: Any = None, fps: float = 30.0) -> Exported:
    """Write the fits file ``fits`` as ``out`` in the format of its extension (see the module
    docstring). model: only for ``.csv`` of a fits file without ``parameter_names`` (hybridfit
    0.3.0 and older; the other formats take the model the file names); fps: the frame rate a
    BVH, JSON or glTF records."""
    kind = export_format(out)
    check_output(out, "output")
    if kind == "CSV":
        from ..fitting.angles import export_angles

        result = export_angles(fits, out, model)
        return Exported(kind, len(result.failed), tuple(int(f) for f in np.flatnonzero(result.failed)))
    if model is not None:
        raise HybridfitError(f"{out}: a {kind} export takes the model the fits file names; a model is given "
                             "only for .csv")
    from .fitted import load_fitted

    from .bvh import check_fps

    check_fps(fps)  # before anything is read
    fitted = load_fitted(fits)
    if kind == "JSON":
        from .tojson import write_json

        write_json(out, fitted, fps)
    elif kind in ("GLB", "glTF"):
        from .gltf import write_gltf

        write_gltf(out, fitted, fps)
    else:
        from .bvh import write_bvh

        write_bvh(out, fitted, fps)
    failed = fitted.result.failed
    return Exported(kind, len(failed), tuple(int(f) for f in np.flatnonzero(failed)))
