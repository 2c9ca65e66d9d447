"""Helpers shared by the forest commands (train, propose, estimate): which frames, and
listing the empty ones. Data sets come from ``hybridfit.datasets.open_dataset``, in camera
coordinates; this module converts nothing."""

from __future__ import annotations

import numpy as np


def frame_indices(ds, frames: str | None) -> np.ndarray:
    """The frames of ``ds`` that ``--frames`` selects (``START:STOP``, as ``_common.frames_range``
    gives it; all for None)."""
    from ..io import frame_slice

    n = len(ds)
    return np.arange(n)[frame_slice(frames, n)]


def report_empty(empty: np.ndarray, indices: np.ndarray, err) -> None:
    """List frames without foreground pixels on ``err`` (at most 10)."""
    bad = indices[np.flatnonzero(empty)]
    for f in bad[:10]:
        print(f"  frame {int(f)}: no foreground pixels (empty result)", file=err)
    if len(bad) > 10:
        print(f"  ... and {len(bad) - 10} more empty frames", file=err)
