"""Helpers shared by the CLI commands: TOML settings files, plugin options, option types
and results files, each validated before any work starts."""

from __future__ import annotations

import argparse
import difflib
import math
import tomllib
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from .. import registry
from ..errors import HybridfitError
from ..datasets.results import read_xyz as read_results  # noqa: F401  (the commands read results files through it)
from ..io import check_paths, require_file


def declare_paths(parser: argparse.ArgumentParser, inputs=(), outputs=(), replaced_folders=()) -> None:
    """Declare which of a command's options (``"--out"``) or positionals (``"proposals"``) name
    what it reads and what it writes (files; ``replaced_folders``: folders it replaces as a
    whole). The command line checks them before the command runs (:func:`check_declared`):
    no output is an input or a special file. Every command declares (a test checks)."""
    parser.set_defaults(paths_declared=(tuple(inputs), tuple(outputs), tuple(replaced_folders)))


def _attr(name: str) -> str:
    return name.lstrip("-").replace("-", "_")


def check_declared(args: argparse.Namespace) -> None:
    """:func:`hybridfit.io.check_paths` on the paths a command declared (``declare_paths``)."""
    inputs, outputs, folders = args.paths_declared
    values = lambda names: {n: getattr(args, _attr(n)) for n in names}  # noqa: E731
    check_paths(values(inputs), values(outputs), values(folders))


#: the deepest nesting of tables a settings file may have (hybridfit's settings nest two or three
#: levels; thousands make the TOML reader or the settings' validation recurse past Python's limit)
MAX_TOML_DEPTH = 32


def load_toml(path: str | None) -> dict[str, Any]:
    """A TOML file as a dict ({} for None), with errors naming the file and line. A UTF-8 byte
    order mark (which some Windows editors write) is skipped."""
    if path is None:
        return {}
    p = require_file(path)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise HybridfitError(f"{p}: not a text file; expected TOML settings") from None
    return _parse_toml(text, f"{p}: ", f"{p}: invalid TOML: ")


def _parse_toml(text: str, where: str, invalid: str) -> dict[str, Any]:
    """``tomllib.loads(text)``, its tables nested at most MAX_TOML_DEPTH deep; errors start
    with ``where`` (an invalid text's with ``invalid``)."""
    try:
        out = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise HybridfitError(f"{invalid}{err}") from None
    except RecursionError:
        out = None
    if out is None or _depth(out) > MAX_TOML_DEPTH:
        raise HybridfitError(f"{where}tables or values nested more than {MAX_TOML_DEPTH} levels deep; hybridfit's "
                             "settings nest a few levels")
    return out


def _depth(value: Any) -> int:
    """How deep tables and arrays nest in ``value`` (a scalar: 0), counted without recursion."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        value, depth = stack.pop()
        children = value.values() if isinstance(value, dict) else value if isinstance(value, list) else None
        if children is not None:
            deepest = max(deepest, depth + 1)
            if depth < MAX_TOML_DEPTH:  # deeper is refused anyway: no need to walk it all
                stack.extend((c, depth + 1) for c in children)
    return deepest


def load_settings(value: str | None, option: str) -> dict[str, Any]:
    """Plugin settings: a TOML file, or inline TOML (``'local_share = 0'``: a value holding "="
    that names no file), errors naming the file or the option."""
    if value is not None and "=" in value and not _is_file(value):
        return _parse_toml(value, f"{option}: ", f"{option} {value!r}: neither a file nor valid inline TOML: ")
    return load_toml(value)


def _is_file(value: str) -> bool:
    """Whether ``value`` names an existing path (a text too long to be a file name names none)."""
    try:
        return Path(value).exists()
    except (OSError, ValueError):
        return False


#: the plugins a command uses when none is named
DEFAULT_PLUGINS = {"model": "hand26", "objective": "clamped-then-soft-l1", "optimizer": "stepwise-pso"}
#: the key of a model settings file that names the model it is for (``hybridfit calibrate`` writes it)
MODEL_KEY = "model"


def load_model_toml(path: str | None, model: str | None) -> tuple[str | None, dict[str, Any]]:
    """A model settings file -> (the model: ``model`` if given, else the one the file names
    under ``MODEL_KEY``, else None; the settings without that key). A file that names
    another model than ``model`` is a user error naming the file and both models."""
    config = load_toml(path)
    named = config.pop(MODEL_KEY, None)
    if named is not None and not isinstance(named, str):
        raise HybridfitError(f"{path}: {MODEL_KEY} must be a model plugin's name, got {named!r}")
    if named is not None and model is not None and named != model:
        raise HybridfitError(f"{path}: settings of model {named!r} (its {MODEL_KEY} key), not of --model {model}; "
                             f"leave --model out or calibrate {model}")
    if named is not None and model is None:
        try:
            registry.get("model", named)
        except HybridfitError as err:
            raise HybridfitError(f"{path}: {MODEL_KEY}: {err}") from None
    return model or named, config


def add_plugin_options(parser: argparse.ArgumentParser) -> None:
    """--model/--objective/--optimizer with their --*-config TOML settings files."""
    g = parser.add_argument_group("plugins")
    g.add_argument("--model", help="hand model plugin (default: the one --model-config names, as `hybridfit "
                   "calibrate` writes it, else hand26)")
    g.add_argument("--model-config", metavar="TOML", help="hand model settings file (`hybridfit calibrate` writes one "
                   "that names its model)")
    g.add_argument("--objective", help="objective plugin, minimised by every stage (default: clamped-then-soft-l1, "
                   "the paper's clamped-confidence for the search and soft-l1 fusion for the local stage; for "
                   "proposals made from results files, the objective the file names: gaussian-mixture)")
    g.add_argument("--objective-config", metavar="TOML", help="objective settings: a TOML file, or inline TOML "
                   "such as 'd_max_mm = 30'")
    g.add_argument("--optimizer", default="stepwise-pso", help="optimizer plugin (default: stepwise-pso)")
    g.add_argument("--optimizer-config", metavar="TOML", help="optimizer settings: a TOML file, or inline TOML "
                   "such as 'local_share = 0' (the paper's schedule)")


def add_keypoint_options(parser: argparse.ArgumentParser) -> None:
    """--mirrored/--labels/--unit: how MediaPipe results and OpenPose keypoints are read
    (``hybridfit.datasets.results.read_keypoints``)."""
    parser.add_argument("--mirrored", action="store_true",
                        help="MediaPipe results: the images MediaPipe saw were flipped horizontally (a selfie view); "
                        "x is negated, so the points are the real hand's")
    parser.add_argument("--labels", choices=("subject", "selfie"), default="subject",
                        help="MediaPipe results: its handedness convention, subject (default; the Tasks API: Left is "
                        "the subject's left hand in an un-mirrored image) or selfie (MediaPipe Hands before the Tasks "
                        "API: the labels assume a mirrored image)")
    parser.add_argument("--unit", choices=("mm", "cm", "m"),
                        help="OpenPose keypoints: the unit of its 3-D keypoints, that of its camera calibration (its "
                        "calibration toolbox writes metres); required for OpenPose input")


def add_fit_options(parser: argparse.ArgumentParser) -> None:
    """--budget/--seed/--jobs/--search-radius: how every frame is fitted."""
    parser.add_argument("--budget", type=budget_int, default=3400, help="objective evaluations per frame (default 3400)")
    parser.add_argument("--seed", type=seed_int, default=0, help="random seed, >= 0 (default 0)")
    parser.add_argument("--jobs", type=positive_int, default=1, help="parallel fitting processes (results do not depend on it)")
    parser.add_argument("--search-radius", type=positive_float, default=60.0,
                        help="position search radius around the initial guess, mm")


def plugin_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword arguments for hybridfit.fit from the plugin options, each plugin created once
    here so that a bad settings file fails before any work, naming the file and key."""
    out = {}
    for kind in ("model", "objective", "optimizer"):
        path = getattr(args, f"{kind}_config")
        if kind == "model":
            name, config = load_model_toml(path, args.model)
        else:
            name, config = getattr(args, kind), load_settings(path, f"--{kind}-config")
        out[kind], out[f"{kind}_config"] = name or DEFAULT_PLUGINS[kind], config
        check_plugin(kind, out[kind], out[f"{kind}_config"], path)
    return out


def check_plugin(kind: str, name: str, config: dict[str, Any], path: str | None) -> None:
    """Create the plugin; errors name the settings file, the key and the closest valid key."""
    where = f"{path}: " if path else ""
    settings = getattr(registry.get(kind, name), "Settings", None)
    try:
        if settings is not None:
            settings.model_validate(config)
        plugin = registry.create(kind, name, config)
        getattr(plugin, "inner", None)  # a wrapper's inner optimiser (stepwise) is checked too
    except ValidationError as err:
        raise settings_error(err, settings, path, f"{kind} {name}") from None
    except HybridfitError as err:
        if path:
            raise HybridfitError(f"{where}{err}") from None
        raise


def validate_settings(cls, config: dict[str, Any], path: str | None, what: str):
    """``cls.model_validate(config)`` (a pydantic settings class) with errors naming the file,
    the key and the closest valid key (``settings_error``)."""
    try:
        return cls.model_validate(config)
    except ValidationError as err:
        raise settings_error(err, cls, path, what) from None


def settings_error(err: ValidationError, cls, path: str | None, what: str) -> HybridfitError:
    """One line for a settings file's ValidationError: ``FILE: unknown key 'k' for WHAT (did you
    mean 'key'? valid keys: ...)`` or ``FILE: key: what is wrong``; nested keys are dotted."""
    parts = []
    for e in err.errors():
        key = ".".join(str(p) for p in e["loc"]) or "(settings)"
        if e["type"] == "extra_forbidden":
            fields = list(_fields_at(cls, e["loc"][:-1]))
            close = difflib.get_close_matches(str(e["loc"][-1]), fields, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            parts.append(f"unknown key {key!r} for {what} ({hint}valid keys: {', '.join(fields)})")
        else:
            parts.append(f"{key}: {e['msg']}")
    return HybridfitError((f"{path}: " if path else "") + "; ".join(parts))


def _fields_at(cls, loc) -> dict[str, Any]:
    """The fields of the (nested) settings table at ``loc`` of pydantic model ``cls``."""
    import typing

    from pydantic import BaseModel

    for part in loc:
        field = getattr(cls, "model_fields", {}).get(str(part))
        models = [] if field is None else [a for a in (field.annotation, *typing.get_args(field.annotation))
                                           if isinstance(a, type) and issubclass(a, BaseModel)]
        if not models:
            return {}
        cls = models[0]
    return getattr(cls, "model_fields", {})


def check_image_format(path: str, option: str = "--out") -> None:
    """Refuse, before any work, an image file name whose format matplotlib cannot write."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    formats = FigureCanvasAgg(Figure()).get_supported_filetypes()
    ext = Path(path).suffix.lower().lstrip(".")
    if ext not in formats:
        raise HybridfitError(f"{option} {path}: cannot write {'.' + ext if ext else 'a file without an extension'} "
                             f"images; use .png (or {', '.join('.' + f for f in sorted(formats) if f != 'png')})")




def _number(text: str, convert, ok, what: str):
    """``convert(text)`` if it is a number that satisfies ``ok``; else an argparse error saying ``what``."""
    try:
        value = convert(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if not ok(value):
        raise argparse.ArgumentTypeError(f"expected {what}, got {value if convert is int else text}")
    return value


#: the largest integer any option takes (numpy's int64): beyond it an option is a typo
MAX_INT = 2**63 - 1


def _at_most(value: int, largest: int, what: str) -> int:
    """``value`` if it is at most ``largest``; else an argparse error saying ``what``."""
    if value > largest:
        raise argparse.ArgumentTypeError(f"expected {what}, got {value}")
    return value


def non_negative_int(text: str) -> int:
    value = _number(text, int, lambda v: v >= 0, "a non-negative integer")
    return _at_most(value, MAX_INT, f"a non-negative integer up to {MAX_INT}")


def seed_int(text: str) -> int:
    """A seed: an integer in [0, 2**64) (seeds are unsigned 64-bit integers)."""
    from ..keys import MAX_SEED

    return _at_most(_number(text, int, lambda v: v >= 0, "a non-negative integer"), MAX_SEED,
                    f"a seed from 0 to 2**64 - 1 = {MAX_SEED}")


def budget_int(text: str) -> int:
    """A budget: objective evaluations per frame, 1 to 1,000,000,000."""
    from ..keys import MAX_BUDGET

    return _at_most(_number(text, int, lambda v: v >= 1, "a positive integer"), MAX_BUDGET,
                    f"a budget from 1 to {MAX_BUDGET:,} evaluations")


def fraction(text: str) -> float:
    """A number in [0, 1)."""
    return _number(text, float, lambda v: 0 <= v < 1, "a number in [0, 1)")


def positive_float(text: str) -> float:
    return _number(text, float, lambda v: math.isfinite(v) and v > 0, "a positive number")


def number_in(low: float, high: float):
    """An option type: a number from ``low`` to ``high`` (NaN and inf refused)."""
    def number(text: str) -> float:
        return _number(text, float, lambda v: low <= v <= high, f"a number from {low:g} to {high:g}")

    number.__name__ = f"number from {low:g} to {high:g}"  # argparse's name for it
    return number


def positive_int(text: str) -> int:
    return _at_most(_number(text, int, lambda v: v >= 1, "a positive integer"), MAX_INT,
                    f"a positive integer up to {MAX_INT}")


#: the one meaning of ``--frames`` in every command that reads frames (``synth`` makes N frames)
FRAMES_HELP = "START:STOP (frames START to STOP-1; either may be left out) or N (the first N, as :N)"


def frames_range(text: str) -> str:
    """``--frames``: ``START:STOP`` (either may be left out) or ``N``, short for ``:N`` (the
    first N frames); the text as ``START:STOP`` for :func:`hybridfit.io.frame_slice`."""
    parts = text.split(":")
    try:
        numbers = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        numbers = []
    if len(parts) == 1 and numbers and numbers[0] is not None and numbers[0] >= 1:
        return f":{numbers[0]}"
    if len(parts) == 2 and numbers:
        return text
    raise argparse.ArgumentTypeError(f"expected START:STOP or N (the first N frames), got {text!r}")


def add_frames_option(parser, what: str = "frames to use") -> None:
    """``--frames`` with its one meaning (:data:`FRAMES_HELP`), default all."""
    parser.add_argument("--frames", type=frames_range, metavar="START:STOP", help=f"{what}: {FRAMES_HELP} "
                        "(default: all)")
