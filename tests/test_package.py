"""``import hybridfit`` is light, and its lazy public names are real and documented."""

import ast
import subprocess
import sys
from pathlib import Path

import hybridfit

INIT = Path(hybridfit.__file__)


def test_every_public_name_resolves_and_is_declared_for_static_readers():
    tree = ast.parse(INIT.read_text())
    block = next(node for node in tree.body if isinstance(node, ast.If) and getattr(node.test, "id", "") == "TYPE_CHECKING")
    declared = {alias.asname or alias.name for node in block.body for alias in node.names}
    public = set(hybridfit.__all__) - {"__version__"}
    assert declared == public == set(hybridfit._LAZY)
    for name in public:
        assert getattr(hybridfit, name) is not None


def test_import_is_light():
    code = "import sys, hybridfit; print(sorted(m for m in ('numba', 'scipy', 'matplotlib') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
