"""The library never imports the command line: every module outside hybridfit.cli loads without it."""

import subprocess
import sys


def test_the_library_does_not_import_the_cli():
    code = (
        "import importlib, pkgutil, sys\n"
        "def walk(package):\n"
        "    for m in pkgutil.iter_modules(package.__path__, package.__name__ + '.'):\n"
        "        if m.name in ('hybridfit.cli', 'hybridfit.__main__'):\n"
        "            continue\n"
        "        module = importlib.import_module(m.name)\n"
        "        if m.ispkg:\n"
        "            walk(module)\n"
        "import hybridfit\n"
        "walk(hybridfit)\n"
        "print(sorted(n for n in sys.modules if n.startswith('hybridfit.cli')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out
