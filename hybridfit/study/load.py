"""Reading a study file: TOML -> a validated :class:`~.spec.Study` whose paths resolve
against the file's folder and exist. Every error names the file and the field path."""

from __future__ import annotations

import tomllib
from pathlib import Path

from pydantic import BaseModel, ValidationError

from ..datasets.skeletons import is_skeleton_file, skeleton
from ..errors import HybridfitError
from .expand import deep_merge, expand
from .spec import Study, validation_error

def _resolve_paths(data: BaseModel, root: Path) -> None:
    for name in ("test", "train", "forest_file", "file", "ground_truth"):
        value = getattr(data, name, None)
        if isinstance(value, list):
            object.__setattr__(data, name, [root / v for v in value])
        elif isinstance(value, Path):
            object.__setattr__(data, name, root / value)
    dataset = getattr(data, "dataset", None)
    if isinstance(dataset, str) and is_skeleton_file(dataset):
        object.__setattr__(data, "dataset", str(root / dataset))


def _check_exists(data: BaseModel, where: str) -> None:
    for name in ("test", "train", "forest_file", "file", "ground_truth"):
        value = getattr(data, name, None)
        for p in value if isinstance(value, list) else [value]:
            if isinstance(p, Path) and not p.exists():
                raise HybridfitError(f"{where}: data.{name}: no such file or folder {p}")
    if isinstance(getattr(data, "dataset", None), str):
        try:
            skeleton(data.dataset)
        except HybridfitError as err:
            raise HybridfitError(f"{where}: data.dataset: {err}") from None


def load_spec(path: str | Path, quick: bool = False) -> Study:
    """Read and validate a study file (with its ``[quick]`` overrides when ``quick``)."""
    path = Path(path)
    if not path.is_file():
        raise HybridfitError(f"{path}: no such study file")
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise HybridfitError(f"{path}: invalid TOML: {err}") from None
    except UnicodeDecodeError:
        raise HybridfitError(f"{path}: not a text file; expected a study file (TOML)") from None
    where = str(path)
    if quick:
        over = raw.get("quick", {})
        if not isinstance(over, dict) or not over:
            raise HybridfitError(f"{path}: --quick needs a [quick] table of overrides")
        parse_spec(raw, where, path.parent)  # the whole file is valid, also what [quick] overrides
        raw = deep_merge(raw, over)
        where = f"{path} (with its [quick] overrides)"
    return parse_spec(raw, where, path.parent)


def parse_spec(raw: dict, where: str = "study", root: Path | None = None) -> Study:
    """Validate a study dict; paths resolve against ``root``; data files must exist."""
    try:
        study = Study.model_validate(raw)
    except ValidationError as err:
        raise validation_error(where, err) from None
    _resolve_paths(study.data, Path(root or "."))
    _check_exists(study.data, where)
    expand(study, where)  # sweep errors now, not when the run reaches them
    return study


