"""The core names no plugin except as a default value (issues 12 and 18): every name of a
reference plugin (a model, objective or optimiser of hybridfit's own entry points) in
hybridfit/ is a function's default argument, a ``default=`` keyword, a pydantic ``Field``
default or the value of a (module, class or dict) default setting, or one of a ``Literal[...]``
type's names (``hybridfit.names``: the built-in names an editor lists), never a comparison or a
plugin the core builds for itself. The conformance suite brings its own model and
objectives."""

from __future__ import annotations

import ast
from importlib.metadata import distribution
from pathlib import Path

import pytest

import hybridfit

CORE = Path(hybridfit.__file__).parent
GROUPS = ("hybridfit.models", "hybridfit.objectives", "hybridfit.optimizers")
#: the names of hybridfit's own plugins, as its distribution declares them
PLUGINS = tuple(sorted(ep.name for ep in distribution("hybridfit").entry_points if ep.group in GROUPS))


def _in_literal(node: ast.AST, parents: dict[ast.AST, ast.AST]) -> bool:
    """``node`` is one of the names of a ``Literal[...]`` type: a list for editors, never logic."""
    parent = parents.get(node)
    if isinstance(parent, ast.Tuple):
        parent = parents.get(parent)
    return isinstance(parent, ast.Subscript) and getattr(parent.value, "id", None) == "Literal"


def _as_default(node: ast.AST, parents: dict[ast.AST, ast.AST]) -> bool:
    if _in_literal(node, parents):
        return True
    parent = parents.get(node)
    if isinstance(parent, ast.arguments):
        return node in parent.defaults or node in parent.kw_defaults
    if isinstance(parent, ast.keyword):
        return parent.arg == "default"
    if isinstance(parent, ast.Call):
        return getattr(parent.func, "id", None) == "Field" and parent.args[:1] == [node]
    if isinstance(parent, (ast.Assign, ast.AnnAssign)):
        return True  # a named default: MODEL = "hand26", model: str = "hand26"
    if isinstance(parent, ast.Dict):
        return isinstance(parents.get(parent), (ast.Assign, ast.AnnAssign)) and node in parent.values
    return False


def offending(source: str) -> list[int]:
    """Line numbers of plugin names used other than as a default value."""
    tree = ast.parse(source)
    parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
    return [n.lineno for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and n.value in PLUGINS and not _as_default(n, parents)]


@pytest.mark.parametrize("path", sorted(CORE.rglob("*.py")), ids=lambda p: str(p.relative_to(CORE)))
def test_the_core_names_plugins_only_as_defaults(path):
    assert offending(path.read_text()) == [], f"{path}: a plugin named other than as a default value"


def test_every_kind_of_reference_plugin_is_checked():
    assert {"hand26", "clamped-confidence", "least-squares", "stepwise-pso", "pso"} <= set(PLUGINS)


def test_the_check_finds_a_comparison_and_a_model_built_by_name():
    assert offending('def f(model="hand26", x=1):\n    return x\nDEFAULT = {"model": "hand26"}\n') == []
    assert offending('if settings.model != "hand26":\n    pass\n') == [1]
    assert offending('ModelName = Literal["hand26", "hand27"]\nOne = Literal["pso"]\n') == []
    assert sorted(offending('if model in ("hand26", "hand27"):\n    pass\nx = Other["pso"]\n')) == [1, 1, 3]
    assert offending('m = registry.create("model", "hand26")\n') == [1]
    assert offending('def check():\n    objective = registry.create("objective", "clamped-confidence")\n') == [2]
