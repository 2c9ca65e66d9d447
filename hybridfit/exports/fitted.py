"""A fits file read back with the model that made it: what every export starts from.

``hybridfit fit --out`` names its model in the fits file: ``model`` (the model plugin's name,
a 0-d string) and ``model_settings`` (its settings, ``json.dumps(model.get_params())``), so
that ``registry.create("model", model, json.loads(model_settings)).forward(params)`` gives
the file's ``model_joints`` (to 1e-6 mm; failed frames aside). :func:`load_fitted` checks
that contract (to :data:`MODEL_JOINTS_TOLERANCE_MM`) and refuses a file without ``model``
(written by an older hybridfit) in one line saying to re-run ``hybridfit fit``, a proposals
file saying to fit it first, and ``model_settings`` that hold a non-finite number or are
nested deeper than :data:`MAX_NESTING`; names are checked as ``load_fits`` checks them.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Any

import numpy as np

from .. import registry
from ..errors import HybridfitError
from ..fitting.angles import check_fits_keys, load_fits
from ..fitting.frames import FitResult
from ..io import load_npz

#: how far the file's ``model_joints`` may be from its model's forward kinematics of ``params``
MODEL_JOINTS_TOLERANCE_MM = 1e-3
#: how deeply ``model_settings`` may nest objects and lists (the settings object itself is level 1)
MAX_NESTING = 32


@dataclass(frozen=True)
class Fitted:
    """A fits file and its model. result: the file as a FitResult (``load_fits``); model: the
    model plugin, created from ``model_name`` and ``model_settings``; frames (F,): each row's
    frame index (the file's ``frames`` when it has them, else 0..F-1)."""

    path: str
    result: FitResult
    model_name: str
    model_settings: dict[str, Any]
    model: Any
    frames: np.ndarray

    @property
    def ok(self) -> np.ndarray:
        """(F,) bool: the frames that were fitted."""
        return ~np.asarray(self.result.failed, dtype=bool)


def _string(data: dict[str, np.ndarray], key: str, where: str) -> str:
    value = data[key]
    if value.ndim != 0 or value.dtype.kind not in "US":
        raise HybridfitError(f"{where}: {key!r} must be one string, got {value.dtype} {value.shape}")
    return str(value)


def load_fitted(path: str | os.PathLike) -> Fitted:
    """Read a fits file with its model (see the module docstring); errors are one line
    naming the file and key."""
    where = str(path)
    data = load_npz(path, "fits")
    check_fits_keys(data, where)
    if "model" not in data:
        raise HybridfitError(f"{where}: written by an older hybridfit (no 'model' key naming the model that "
                             "fitted it); re-run `hybridfit fit` to export it")
    name = _string(data, "model", where)
    if not name:
        raise HybridfitError(f"{where}: names no model (fitted with a model plugin that is not registered), "
                             "so its skeleton is unknown; fit with a registered model")
    if "model_settings" not in data:
        raise HybridfitError(f"{where}: missing key 'model_settings' (the settings of model {name!r}); "
                             "re-run `hybridfit fit`")
    settings = _settings(_string(data, "model_settings", where), where)
    model = _create_model(name, settings, where)
    result = load_fits(path)
    F = len(result.params)
    if tuple(result.parameter_names) != tuple(model.parameter_names):
        raise HybridfitError(f"{where}: its parameter_names are not model {name!r}'s; re-run `hybridfit fit`")
    J = model.n_joints
    if "model_joints" not in data or result.model_joints.shape != (F, J, 3):
        got = result.model_joints.shape if "model_joints" in data else "none"
        raise HybridfitError(f"{where}: 'model_joints' must be ({F}, {J}, 3) mm (model {name!r}'s joints), got {got}")
    if "joints" not in data:
        raise HybridfitError(f"{where}: missing key 'joints' (the fitted points, (frames, points, 3) mm)")
    Q = result.joints.shape[1]
    if len(result.joint_names) != Q:
        raise HybridfitError(f"{where}: {len(result.joint_names)} 'joint_names' for {Q} 'joints' per frame")
    ok = ~result.failed
    for key in ("joints", "model_joints"):
        finite = np.isfinite(getattr(result, key)).all(axis=(1, 2))
        if not finite[ok].all():
            first = int(np.flatnonzero(ok & ~finite)[0])
            raise HybridfitError(f"{where}: {key!r} has NaN or inf values in frame {first}, not marked failed")
    frames = data.get("frames")
    if frames is None:
        frames = np.arange(F)
    elif frames.shape != (F,) or frames.dtype.kind not in "iu":
        raise HybridfitError(f"{where}: 'frames' must be {F} integer indices, got {frames.dtype} {frames.shape}")
    if ok.any():
        off = np.linalg.norm(model.forward(result.params[ok]) - result.model_joints[ok], axis=-1).max(axis=1)
        off = np.where(np.isfinite(off), off, np.inf)  # NaN (overflowing parameters) is not a match
        worst = int(np.argmax(off))
        if off[worst] > MODEL_JOINTS_TOLERANCE_MM:
            raise HybridfitError(
                f"{where}: 'model_joints' are not the joints of model {name!r} for 'params' (off by {off[worst]:.3g} mm in "
                f"frame {int(np.flatnonzero(ok)[worst])}): the model or its settings changed since the fit, or the "
                "fit bent the model (refined bones); re-run `hybridfit fit`")
    return Fitted(where, result, name, settings, model, np.asarray(frames))


def _settings(text: str, where: str) -> dict[str, Any]:
    """``model_settings`` as a dict: JSON, an object, nested at most MAX_NESTING deep, every number finite."""
    deep = f"{where}: 'model_settings' is nested deeper than {MAX_NESTING} levels; re-run `hybridfit fit`"
    try:
        settings = json.loads(text)
    except RecursionError:
        raise HybridfitError(deep) from None
    except ValueError as err:  # JSONDecodeError, or an integer of too many digits
        raise HybridfitError(f"{where}: 'model_settings' is not JSON ({err})") from None
    if not isinstance(settings, dict):
        raise HybridfitError(f"{where}: 'model_settings' must be a JSON object, got {type(settings).__name__}")
    todo = [(settings, "", 1)]
    while todo:
        value, key, depth = todo.pop()
        if isinstance(value, (dict, list)):
            if depth > MAX_NESTING:
                raise HybridfitError(deep)
            items = value.items() if isinstance(value, dict) else enumerate(value)
            todo.extend((v, f"{key}.{k}" if isinstance(value, dict) else f"{key}[{k}]", depth + 1) for k, v in items)
        elif isinstance(value, float) and not np.isfinite(value):
            raise HybridfitError(f"{where}: 'model_settings' holds {value} at {key.lstrip('.')}; settings must be "
                                 "finite numbers")
    return settings


def _create_model(name: str, settings: dict[str, Any], where: str):
    try:
        return registry.create("model", name, settings)
    except HybridfitError as err:  # an unknown model, or settings it refuses
        raise HybridfitError(f"{where}: 'model' {name!r} with its 'model_settings': {err}") from None
