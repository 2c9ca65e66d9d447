"""Skeletons as data: each dataset's annotated points and the model point each maps onto.

A skeleton is a small TOML file. The built-in ones (``icvl``, ``nyu``, ``nyu36``, ``msra``,
``mediapipe``, ``mano``) ship in ``hybridfit/datasets/skeleton_files/``; a user's own file
is accepted wherever a dataset name is: ``skeleton("path/to/my.toml")`` (a name ending in
``.toml`` or containing a ``/`` is a path). The format::

    name = "mydata"          # optional; default: the file's name without .toml
    model = "hand26"         # optional; the model whose points [points] names
    convention = "icvl"      # optional; camera convention of its results files (conventions.py)
    fingertips = ["thumb", "index"]      # names from [points]

    [points]                 # the dataset's points, in file order -> a model point
    palm = "my_palm"         # a derived point defined below
    thumb = "thumb_tip"      # or a point of the model (hand26: a joint, or palm_centre)
    index = "index_tip"

    [derived.my_palm]        # a derived point: weights of model joints, summing to 1
    wrist = 0.5
    middle_mcp = 0.5

Derived points' weights are defaults from the datasets' annotation conventions (each file
says where they come from); ``hybridfit calibrate`` fits them to annotated frames and
writes them into the model config. Errors in a file name the file and the key, with the
closest valid key for a typo.
"""

from __future__ import annotations

import difflib
import functools
import json
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import HybridfitError
from .conventions import CONVENTIONS, Convention

#: the folder of the built-in skeleton files
BUILTIN_DIR = Path(__file__).with_name("skeleton_files")
_KEYS = ("name", "model", "convention", "fingertips", "points", "derived")
_DEFAULT_MODEL = "hand26"
#: each derived-point weight lies in this range (it may extrapolate a little beyond its joints)
DERIVED_WEIGHT_RANGE = (-1.0, 2.0)


@dataclass(frozen=True)
class Skeleton:
    """A dataset's points: ``names`` (J,) its own names in file order, ``model_names`` (J,)
    the model point each maps onto, ``fingertips`` indices of the fingertips; ``model`` the
    model plugin those points belong to, ``convention`` the camera convention name (or
    None), ``source`` the file it was read from."""

    dataset: str
    names: tuple[str, ...]
    model_names: tuple[str, ...]
    fingertips: tuple[int, ...]
    derived_weights: dict[str, dict[str, float]] = field(default_factory=dict, hash=False, repr=False)
    convention: str | None = None
    model: str = _DEFAULT_MODEL
    source: str = ""

    @property
    def derived(self) -> dict[str, dict[str, float]]:
        """The derived points this skeleton needs, with their default joint weights (copies)."""
        return {n: dict(w) for n, w in self.derived_weights.items()}

    def __len__(self) -> int:
        return len(self.names)


def _key(name: str) -> str:
    """A TOML key as written in a file: bare, or quoted (one line) when it needs quotes."""
    return name if re.fullmatch(r"[A-Za-z0-9_-]+", name) else json.dumps(name)


def _number(w: Any) -> bool:
    try:
        return not isinstance(w, bool) and isinstance(w, (int, float)) and math.isfinite(float(w))
    except OverflowError:  # an integer beyond float range
        return False


def _closest(word: str, choices) -> str:
    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _parse(raw: dict[str, Any], where: str, default_name: str) -> Skeleton:
    """A skeleton from a TOML dict; errors are HybridfitErrors naming ``where`` and the key.
    Checks the file's own consistency; :func:`check_model` checks the model's point names."""

    def fail(key: str, msg: str) -> HybridfitError:
        return HybridfitError(f"{where}: {key}: {msg}")

    for key in raw:
        if key not in _KEYS:
            raise fail(_key(key), f"unknown key{_closest(key, _KEYS)}; keys: {', '.join(_KEYS)}")
    for key in ("name", "model", "convention"):
        if key in raw and (not isinstance(raw[key], str) or not raw[key].strip()):
            raise fail(key, f"must be a non-empty string, got {raw[key]!r}")
    if "convention" in raw:
        if raw["convention"] not in CONVENTIONS:
            raise fail("convention", f"unknown convention {raw['convention']!r}{_closest(raw['convention'], CONVENTIONS)};"
                       f" known: {', '.join(CONVENTIONS)}")

    points = raw.get("points")
    if not isinstance(points, dict) or not points:
        raise fail("points", "missing or empty; a table of dataset point name = model point name")
    used: dict[str, str] = {}
    for name, target in points.items():
        if not isinstance(target, str) or not target:
            raise fail(f"points.{_key(name)}", f"must be a model point name (a string), got {target!r}")
        if target in used:
            raise fail(f"points.{_key(name)}", f"maps onto {target!r} like points.{_key(used[target])}; "
                       "each point needs its own model point (define a derived point)")
        used[target] = name

    derived_raw = raw.get("derived", {})
    if not isinstance(derived_raw, dict):
        raise fail("derived", f"must be a table of derived points, got {derived_raw!r}")
    derived: dict[str, dict[str, float]] = {}
    for dname, weights in derived_raw.items():
        key = f"derived.{_key(dname)}"
        if dname not in used:
            raise fail(key, f"not used by any point{_closest(dname, list(used))}")
        if not isinstance(weights, dict) or not weights:
            raise fail(key, "must be a non-empty table of joint = weight")
        lo, hi = DERIVED_WEIGHT_RANGE
        for joint, w in weights.items():
            if not _number(w):
                raise fail(f"{key}.{_key(joint)}", f"must be a finite number, got {w!r}")
            if not lo <= w <= hi:
                raise fail(f"{key}.{_key(joint)}", f"weight {w:g} is outside [{lo:g}, {hi:g}]: a derived point is a "
                           "weighted mean of joints (weights summing to 1); weights this large put it far outside "
                           "the hand")
        total = math.fsum(weights.values())
        if abs(total - 1.0) > 1e-6:
            raise fail(key, f"weights sum to {total:g}; they must sum to 1 (so the point moves rigidly with the hand)")
        derived[dname] = {j: float(w) for j, w in weights.items()}

    tips = raw.get("fingertips")
    if not isinstance(tips, list) or not all(isinstance(t, str) for t in tips):
        raise fail("fingertips", f"must be a list of point names from [points], got {tips!r}")
    names = list(points)
    for i, t in enumerate(tips):
        if t not in points:
            raise fail(f"fingertips[{i}]", f"{t!r} is not a point{_closest(t, names)}")
    if len(set(tips)) != len(tips):
        raise fail("fingertips", "lists a point twice")

    return Skeleton(
        dataset=raw.get("name", default_name),
        names=tuple(names),
        model_names=tuple(points.values()),
        fingertips=tuple(names.index(t) for t in tips),
        derived_weights=derived,
        convention=raw.get("convention"),
        model=raw.get("model", _DEFAULT_MODEL),
        source=where,
    )


def check_model(sk: Skeleton) -> None:
    """Check that every point names a point of ``sk.model`` (a joint or one of its derived
    points) or a derived point of the file, and that derived points weigh its joints."""
    from .. import registry

    try:
        model = registry.create("model", sk.model)
    except HybridfitError as err:
        raise HybridfitError(f"{sk.source}: model: {err}") from None
    joints = tuple(model.joint_names)
    known = (*joints, *model.derived_points, *sk.derived_weights)
    for name, target in zip(sk.names, sk.model_names):
        if target not in known:
            raise HybridfitError(f"{sk.source}: points.{_key(name)}: unknown {sk.model} point {target!r}"
                                 f"{_closest(target, known)}")
    for dname, weights in sk.derived_weights.items():
        if dname in joints:
            raise HybridfitError(f"{sk.source}: derived.{_key(dname)}: has the name of a {sk.model} joint")
        for joint in weights:
            if joint not in joints:
                raise HybridfitError(f"{sk.source}: derived.{_key(dname)}.{_key(joint)}: unknown {sk.model} joint"
                                     f"{_closest(joint, joints)}")


def load_skeleton(path: str | Path) -> Skeleton:
    """A skeleton TOML file, fully checked (the file's consistency and its model's points)."""
    p = Path(path)
    if p.is_dir():
        raise HybridfitError(f"{p}: is a folder, not a skeleton file")
    if not p.is_file():
        raise HybridfitError(f"{p}: no such skeleton file")
    stat = p.stat()
    return _load_checked(str(p), str(p.resolve()), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=32)
def _load_checked(shown: str, resolved: str, mtime_ns: int, size: int) -> Skeleton:
    sk = _read(Path(resolved), shown)
    check_model(sk)
    return sk


def _read(path: Path, shown: str) -> Skeleton:
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise HybridfitError(f"{shown}: not a UTF-8 text file") from None
    except tomllib.TOMLDecodeError as err:
        raise HybridfitError(f"{shown}: invalid TOML: {err}") from None
    return _parse(raw, shown, path.stem)


#: the built-in skeletons by name (read at import; their model points are checked by the tests)
SKELETONS: dict[str, Skeleton] = {p.stem: _read(p, str(p)) for p in sorted(BUILTIN_DIR.glob("*.toml"))}

#: NYU's 36 annotated points (joint_data.mat order): 6 per finger F1 (little) .. F4 (index), thumb, palm
NYU36: tuple[str, ...] = SKELETONS["nyu36"].names
#: the common 14-point evaluation subset (Tompson et al. 2014), indices into NYU36
NYU14: tuple[int, ...] = tuple(NYU36.index(n) for n in SKELETONS["nyu"].names)


def is_skeleton_file(dataset: str) -> bool:
    """Whether a ``--dataset`` value names a skeleton file (ends in .toml or has a /)."""
    return dataset.endswith(".toml") or "/" in dataset or "\\" in dataset


def skeleton(dataset: str) -> Skeleton:
    """The skeleton of a dataset: a built-in name (icvl, nyu, nyu36, msra, mediapipe, mano)
    or the path of a skeleton TOML file."""
    dataset = str(dataset)
    if dataset.lower() in SKELETONS:
        return SKELETONS[dataset.lower()]
    if is_skeleton_file(dataset):
        return load_skeleton(dataset)
    raise HybridfitError(f"unknown dataset {dataset!r}{_closest(dataset.lower(), SKELETONS)} "
                         f"(known: {', '.join(SKELETONS)}; or a skeleton .toml file)")


def to_toml(sk: Skeleton) -> str:
    """A skeleton as the text of a skeleton file (a start for one's own: ``load_skeleton``
    reads it back equal, its ``name`` included)."""
    import tomli_w

    doc: dict[str, Any] = {"name": sk.dataset, "model": sk.model}
    if sk.convention is not None:
        doc["convention"] = sk.convention
    doc["fingertips"] = [sk.names[i] for i in sk.fingertips]
    doc["points"] = dict(zip(sk.names, sk.model_names))
    if sk.derived_weights:
        doc["derived"] = {d: {j: float(w) for j, w in weights.items()} for d, weights in sk.derived_weights.items()}
    return tomli_w.dumps(doc)


def with_derived_points(model_config: dict, dataset: str, setting: str = "derived_points") -> dict:
    """Model settings with the skeleton's derived points added where the config lacks them,
    under the model's derived-points setting ``setting`` (``HandModel.derived_points_setting``)."""
    derived = dict(model_config.get(setting, {}))
    for name, weights in skeleton(dataset).derived.items():
        derived.setdefault(name, weights)
    return {**model_config, setting: derived}


def dataset_model_config(model: str, model_config: dict, dataset: str | None) -> dict:
    """The fitting model's settings for a dataset's skeleton: a model that declares a
    derived-points setting and has every joint the skeleton's derived points weigh gets those
    points (whichever model the skeleton file names: a model with the same joint names maps
    the same way); any other model, a skeleton without derived points and no dataset:
    unchanged (a point the model then lacks is named when it is used)."""
    if not dataset or not skeleton(dataset).derived_weights:
        return dict(model_config)
    from .. import registry

    instance = registry.create("model", model, model_config)
    setting = instance.derived_points_setting
    needed = {j for weights in skeleton(dataset).derived_weights.values() for j in weights}
    if setting is None or not needed <= set(instance.joint_names):
        return dict(model_config)
    return with_derived_points(model_config, dataset, setting)


def convention(dataset: str) -> Convention:
    """The convention of a dataset's skeleton (a built-in name or a skeleton file)."""
    sk = skeleton(dataset)
    if sk.convention is None:
        raise HybridfitError(f"the {sk.dataset} skeleton names no camera convention, needed for results files "
                             f"in pixels (u, v, d); a skeleton file sets one: convention = {' or '.join(map(repr, CONVENTIONS))}")
    return CONVENTIONS[sk.convention]


def fit_settings(names, n_points: int, dataset: str | None, model: str, model_config: dict,
                 where: str) -> tuple[list[str] | None, dict]:
    """The point names and model settings to fit a proposals file with: its own ``names``
    (or, without them, the dataset skeleton's model names, which must number ``n_points``)
    and ``model_config`` with the skeleton's derived points. Every name must be a point of
    the model; errors name ``where`` (the file)."""
    from .. import registry

    if dataset:
        sk = skeleton(dataset)
        if names is None:
            if n_points != len(sk):
                raise HybridfitError(f"{where}: {n_points} points, but the {sk.dataset} skeleton has {len(sk)}"
                                     f"{_skeletons_hint(n_points)}")
            names = sk.model_names
        model_config = dataset_model_config(model, model_config, dataset)
    elif names is None:
        joints = registry.create("model", model, model_config).n_joints
        if n_points != joints:
            raise HybridfitError(f"{where}: {n_points} points without joint_names, and model {model} has {joints} "
                                 f"joints: pass --dataset{_skeletons_hint(n_points, ' (')}{')' * bool(_of_size(n_points))}"
                                 " or store the points' joint_names in the file")
    names = None if names is None else [str(n) for n in names]
    if names is not None:
        instance = registry.create("model", model, model_config)
        if names != list(instance.joint_names):
            try:
                instance.point_matrix(names)
            except HybridfitError as err:  # one message: the points the model lacks, and what gives them
                lacking = [n for n in names if n not in instance.point_names]
                raise HybridfitError(f"{where}: {err}{_missing_points_hint(lacking, instance, dataset)}") from None
    return names, model_config


def _missing_points_hint(missing: list[str], model, dataset: str | None) -> str:
    """What gives a model the points it lacks: the built-in skeletons that define them all as
    derived points of its joints (``--dataset``), else another model or the model's own
    derived-points setting. Never a skeleton that would not help (passing it would only move the error)."""
    joints = set(model.joint_names)
    them, points = ("it", "a derived point") if len(missing) == 1 else ("them", "derived points")
    helping = [n for n, sk in SKELETONS.items()
               if n != dataset and set(missing) <= set(sk.derived_weights)
               and all(set(sk.derived_weights[m]) <= joints for m in missing)]
    if helping:
        return (f"; {' and '.join(helping)} define{'s' if len(helping) == 1 else ''} {them} as {points} of its "
                f"joints: pass --dataset {helping[0]}")
    setting = model.derived_points_setting
    if setting is None:
        return f"; fit with a model that has {them} (--model)"
    return (f"; fit with a model that has {them} (--model), or define {them} as {points} of its joints (its "
            f"{setting} setting, in --model-config)")


def _of_size(n_points: int) -> list[str]:
    return [n for n, sk in SKELETONS.items() if len(sk) == n_points]


def _skeletons_hint(n_points: int, lead: str = "; ") -> str:
    """'; the skeletons with N points: icvl, ...' (empty when none has N points)."""
    names = _of_size(n_points)
    return f"{lead}{n_points}-point skeletons: {', '.join(names)}" if names else ""
