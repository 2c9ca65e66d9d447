"""The package installs: a wheel built offline from the checkout, installed into a fresh
virtual environment, works from a folder outside the checkout, with every third-party
example package (examples/: a model, an objective and two optimisers) installed beside it.

The environment sees this interpreter's packages (numpy, numba, ...) but not its
hybridfit: the test fails unless ``hybridfit`` and ``hybridfit_plugins`` are imported from
the wheel's files inside the new environment. Most commands run with numba's JIT off
(``NUMBA_DISABLE_JIT=1``), each example's fit included; one fit runs compiled, as users run
it, numba caching its functions inside the new environment. That fit compiles every kernel
from scratch (a minute or more of one core), so it runs in the background from the moment
the environment is ready: tests/conftest.py runs this module's quick tests first (the first
builds the environment) and its slow ones (``run_last``) after the rest of the suite, which
runs meanwhile on the other core.
"""

from __future__ import annotations

import ast
import os
import shlex
import shutil
import site
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: folder: (kind, registered name) of every example plugin package
EXAMPLES = {"hybridfit-random-restart": ("optimizer", "random-restart"), "hybridfit-numpy-pso": ("optimizer", "numpy-pso"),
            "hybridfit-numpy-objective": ("objective", "numpy-clamped"), "hybridfit-tripod-hand": ("model", "tripod-hand")}
#: what building the wheel reads (a file pyproject.toml needs and this list lacks fails the build)
BUILD_INPUTS = ("pyproject.toml", "setup.py", "README.md", "LICENSE", "hybridfit", "plugins")
_BUILD_LEFTOVERS = shutil.ignore_patterns("build", "dist", "*.egg-info", "__pycache__")
PIP_OFFLINE = ["-m", "pip", "--disable-pip-version-check", "--no-input"]
PIP_INSTALL = [*PIP_OFFLINE, "install", "--quiet", "--no-deps", "--no-build-isolation", "--no-index"]


def _copy(paths, source: Path, target: Path) -> Path:
    """Copy (setuptools builds inside the source tree: never in the checkout itself)."""
    target.mkdir(parents=True)
    for name in paths:
        src = source / name
        if src.is_dir():
            shutil.copytree(src, target / name, ignore=_BUILD_LEFTOVERS)
        else:
            shutil.copy2(src, target / name)
    return target


#: the compiled fit running in the background (see the module's docstring): its process and folder
_COMPILED: dict = {}


def _check(cmd, cwd: Path, env: dict) -> str:
    done = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True)
    assert done.returncode == 0, f"{cmd} exited {done.returncode}:\n{done.stdout}\n{done.stderr}"
    return done.stdout


@pytest.fixture(scope="session")
def env(tmp_path_factory):
    """(python, hybridfit script, work folder, environment variables) of a fresh virtual
    environment holding the wheel and the example plugin packages; starts the compiled fit
    (:func:`test_a_compiled_fit_from_the_wheel`) in the background."""
    tmp = tmp_path_factory.mktemp("install")
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    if sys.prefix != sys.base_prefix:  # this interpreter is itself a venv: see its packages too (not its .pth hooks)
        paths = [p for p in site.getsitepackages() if Path(p).is_dir()]
        purelib = subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                                 check=True, capture_output=True, text=True).stdout.strip()
        Path(purelib, "outer-environment.pth").write_text("\n".join(paths) + "\n")
    variables = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    variables |= {"NUMBA_DISABLE_JIT": "1", "PYTHONWARNINGS": "ignore", "MPLBACKEND": "Agg"}
    work = tmp / "work"
    work.mkdir()

    source = _copy(BUILD_INPUTS, ROOT, tmp / "hybridfit-src")
    _check([python, *PIP_OFFLINE, "wheel", "--quiet", "--no-deps", "--no-build-isolation", "--no-index",
            "--wheel-dir", tmp / "dist", source], work, variables)
    (wheel,) = (tmp / "dist").glob("hybridfit-*.whl")
    # --ignore-installed: an editable hybridfit in the base environment is left alone and shadowed
    _check([python, *PIP_INSTALL, "--ignore-installed", wheel], work, variables)
    for folder in EXAMPLES:
        example = ROOT / "examples" / folder
        _check([python, *PIP_INSTALL, _copy([p.name for p in example.iterdir()], example, tmp / folder)], work,
               variables)
    script = venv / "bin" / "hybridfit"
    compiled = _COMPILED["folder"] = tmp / "compiled"
    compiled.mkdir()
    commands = [[script, "synth", "proposals", "--frames", "3", "--seed", "4", "--out", "three.npz"],
                [script, "fit", "three.npz", "--budget", "400", "--out", "three-fit.npz"]]
    with open(compiled / "out.txt", "w") as out, open(compiled / "err.txt", "w") as err:  # files: never a full pipe
        _COMPILED["fit"] = subprocess.Popen(
            ["/bin/sh", "-c", " && ".join(shlex.join(map(str, c)) for c in commands)], cwd=compiled, stdout=out,
            stderr=err, env={k: v for k, v in variables.items() if k != "NUMBA_DISABLE_JIT"})  # numba on, as users run it
    yield python, script, work, variables
    if _COMPILED["fit"].poll() is None:  # its test was not selected
        _COMPILED["fit"].kill()
        _COMPILED["fit"].wait()


def _checkout_version() -> str:
    tree = ast.parse((ROOT / "hybridfit" / "__init__.py").read_text())
    return next(node.value.value for node in tree.body if isinstance(node, ast.Assign)
                and any(getattr(t, "id", None) == "__version__" for t in node.targets))


def test_the_wheel_is_what_is_imported(env):
    python, _, work, variables = env
    out = _check([python, "-c", (
        "import importlib.metadata as m, hybridfit, hybridfit_plugins, hybridfit_random_restart as rr\n"
        "from hybridfit.datasets.skeletons import skeleton\n"
        "for module in (hybridfit, hybridfit_plugins, rr): print(module.__file__)\n"
        "print(hybridfit.__version__, m.version('hybridfit'))\n"
        "print(*(len(skeleton(name)) for name in ('icvl', 'nyu', 'msra')))\n"
        "print(*sorted(p.as_posix() for p in m.distribution('hybridfit').files if p.name.startswith('LICENSE')))"
    )], work, variables).splitlines()
    venv = python.parents[1]
    for path in out[:3]:
        assert Path(path).is_relative_to(venv), f"{path} is not the installed wheel's (outside {venv})"
    assert out[3].split() == [_checkout_version()] * 2  # one version: the package's and the wheel's metadata
    assert out[4].split() == ["16", "14", "21"]  # package data: the built-in skeleton files
    licences = out[5].split()  # the project's, and the vendored three.js's beside its files
    assert len(licences) == 2 and licences[1] == "hybridfit/exports/three/LICENSE", licences
    assert licences[0].endswith(".dist-info/LICENSE") or licences[0].endswith(".dist-info/licenses/LICENSE"), licences


def test_the_wheel_is_typed_and_knows_its_version(env):
    """PEP 561: py.typed ships in the wheel, so type checkers and IDEs read hybridfit's annotations."""
    python, hybridfit, work, variables = env
    out = _check([python, "-c", "import hybridfit, pathlib; print((pathlib.Path(hybridfit.__file__).parent / "
                  "'py.typed').is_file())"], work, variables)
    assert out.strip() == "True"
    assert _check([hybridfit, "--version"], work, variables).strip() == f"hybridfit {_checkout_version()}"


def test_plugins_lists_every_plugin_from_the_wheel_and_the_example(env):
    _, hybridfit, work, variables = env
    out = _check([hybridfit, "plugins"], work, variables)
    assert "FAILED" not in out, out
    lines = {line.split()[0]: line for line in out.splitlines() if line.startswith("  ")}
    for name in ("hand26", "hand27", "clamped-confidence", "stepwise-pso", "pso"):
        assert "[hybridfit]" in lines[name]
    for folder, (_, name) in EXAMPLES.items():
        assert f"[{folder}]" in lines[name]


@pytest.mark.run_last  # after the compiled fit (started by env in the background) is done or nearly
def test_a_fit_and_its_angles_from_outside_the_checkout(env):
    _, hybridfit, work, variables = env
    _check([hybridfit, "synth", "proposals", "--frames", "2", "--seed", "3", "--out", "frames.npz"], work, variables)
    out = _check([hybridfit, "fit", "frames.npz", "--budget", "300", "--out", "fit.npz"], work, variables)
    assert "fitted 2/2 frames" in out
    _check([hybridfit, "export-angles", "fit.npz", "--out", "angles.csv"], work, variables)
    header = (work / "angles.csv").read_text().splitlines()[0]
    assert header.startswith("frame,failed,x_mm,y_mm,z_mm,qw,qx,qy,qz,thumb_cmc_flexion_deg,")
    for folder, (kind, name) in EXAMPLES.items():
        given = "frames.npz"
        if kind == "model":  # proposals of the model's own points
            given = "tripod.npz"
            _check([hybridfit, "synth", "proposals", "--frames", "2", "--model", name, "--out", given], work, variables)
        out = _check([hybridfit, "fit", given, "--budget", "300", f"--{kind}", name, "--out", f"fit-{name}.npz"],
                     work, variables)
        assert "fitted 2/2 frames" in out, (folder, out)


@pytest.mark.run_last
def test_a_compiled_fit_from_the_wheel(env):
    """Synthetic proposals and a fit with numba on, started by ``env`` in the background."""
    code = _COMPILED["fit"].wait(timeout=1800)
    out, err = ((_COMPILED["folder"] / name).read_text() for name in ("out.txt", "err.txt"))
    assert code == 0, f"exited {code}:\n{out}\n{err}"
    assert "wrote 3 synthetic frames" in out and "fitted 3/3 frames" in out, out
