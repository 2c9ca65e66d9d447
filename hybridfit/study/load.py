"""Reading a study file: TOML -> a validated :class:`~.spec.Study` whose paths resolve
against the file's folder and exist. Every error names the file and the field path.

The file is UTF-8, with or without a byte-order mark. Names (the study's, its variants' and
grid values) holding control characters are refused (:func:`hybridfit.text.check_name`);
data files must be regular files or folders (a FIFO or a device would be read forever).
A sweep is counted before it is expanded: one of more than ``MAX_TRIALS`` variants is refused
unless ``allow_large`` (its expansion alone takes minutes and gigabytes)."""

from __future__ import annotations

import tomllib
from pathlib import Path

from pydantic import BaseModel, ValidationError

from ..datasets.skeletons import is_skeleton_file, skeleton
from ..errors import HybridfitError
from ..text import check_name
from .expand import MAX_TRIALS, check_size, count_variants, deep_merge, expand
from .spec import Study, validation_error

_PATHS = ("test", "train", "forest_file", "file", "ground_truth")


def _resolve_paths(data: BaseModel, root: Path) -> None:
    for name in _PATHS:
        value = getattr(data, name, None)
        if isinstance(value, list):
            object.__setattr__(data, name, [root / v for v in value])
        elif isinstance(value, Path):
            object.__setattr__(data, name, root / value)
    dataset = getattr(data, "dataset", None)
    if isinstance(dataset, str) and is_skeleton_file(dataset):
        object.__setattr__(data, "dataset", str(root / dataset))


def _check_exists(data: BaseModel, where: str) -> None:
    dataset = getattr(data, "dataset", None)
    files = [(name, p) for name in _PATHS for p in _as_list(getattr(data, name, None)) if isinstance(p, Path)]
    if isinstance(dataset, str) and is_skeleton_file(dataset):
        files.append(("dataset", Path(dataset)))
    for name, p in files:
        if not p.exists():
            if name != "dataset":  # a skeleton file's own message says more (below)
                raise HybridfitError(f"{where}: data.{name}: no such file or folder {p}")
        elif not p.is_file() and not p.is_dir():
            raise HybridfitError(f"{where}: data.{name}: {p} is not a regular file (a FIFO, device or socket, which "
                                 "would be read forever); give a file or a folder")
    if isinstance(dataset, str):
        try:
            skeleton(dataset)
        except HybridfitError as err:
            raise HybridfitError(f"{where}: data.dataset: {err}") from None


def _as_list(value) -> list:
    return value if isinstance(value, list) else [value]


def load_spec(path: str | Path, quick: bool = False, allow_large: bool = False) -> Study:
    """Read and validate a study file (with its ``[quick]`` overrides when ``quick``); a sweep
    of more than ``MAX_TRIALS`` variants needs ``allow_large``."""
    path = Path(path)
    if path.is_dir():
        raise HybridfitError(f"{path}: is a folder; give a study file (TOML, see studies/)")
    if not path.exists():
        raise HybridfitError(f"{path}: no such study file")
    if not path.is_file():
        raise HybridfitError(f"{path}: not a regular file (a FIFO, device or socket); give a study file (TOML)")
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except tomllib.TOMLDecodeError as err:
        raise HybridfitError(f"{path}: invalid TOML: {err}") from None
    except UnicodeDecodeError:
        raise HybridfitError(f"{path}: not a text file; expected a study file (TOML)") from None
    where = str(path)
    if quick:
        over = raw.get("quick", {})
        if not isinstance(over, dict) or not over:
            raise HybridfitError(f"{path}: --quick needs a [quick] table of overrides")
        full = _validate(raw, where, path.parent)  # the whole file is valid, also what [quick] overrides
        if allow_large or count_variants(full) <= MAX_TRIALS:  # (a huge full sweep is not expanded for --quick)
            expand(full, where)
        raw = deep_merge(raw, over)
        where = f"{path} (with its [quick] overrides)"
    return parse_spec(raw, where, path.parent, allow_large)


def parse_spec(raw: dict, where: str = "study", root: Path | None = None, allow_large: bool = False) -> Study:
    """Validate a study dict; paths resolve against ``root``; data files must exist. A sweep of
    more than ``MAX_TRIALS`` variants is refused before it is expanded, unless ``allow_large``."""
    study = _validate(raw, where, root)
    if count_variants(study) > MAX_TRIALS:  # every variant is a trial at least
        check_size(study, allow_large, where)
    expand(study, where)  # sweep errors now, not when the run reaches them
    return study


def _validate(raw: dict, where: str, root: Path | None) -> Study:
    """The study without its sweep expanded: its schema, its name and its data files checked."""
    try:
        study = Study.model_validate(raw)
    except ValidationError as err:
        raise validation_error(where, err) from None
    check_name(study.name, f"{where}: name")
    _resolve_paths(study.data, Path(root or "."))
    _check_exists(study.data, where)
    return study
