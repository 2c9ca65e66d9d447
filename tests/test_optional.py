"""Optional libraries (CasADi, NLopt, pymoo, cma, dask): a missing one makes what needs it
unavailable, with the ``pip install`` line that fixes it, and nothing else.

A missing library is simulated: ``sys.modules[name] = None`` in this process, or an import
blocker in a fresh interpreter (a core-only install, as far as imports can tell).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import hybridfit
from hybridfit import optional, registry
from hybridfit.cli import main
from hybridfit.optional import MissingLibrary
from hybridfit.plugin import Plugin

#: optional plugin -> (the library it imports, the extra that installs it)
OPTIONAL_PLUGINS = {"nlopt": ("nlopt", "nlopt"), "casadi-ik": ("casadi", "casadi"), "pymoo": ("pymoo", "pymoo")}
OPTIONAL_LIBRARIES = ("casadi", "nlopt", "pymoo", "cma", "dask", "distributed")


def _block(monkeypatch, *names):
    for name in names:
        monkeypatch.setitem(sys.modules, name, None)


def test_missing_names_only_what_cannot_be_imported(monkeypatch):
    _block(monkeypatch, "nlopt")
    assert optional.missing({"numpy": "numpy", "nlopt": "hybridfit[nlopt]", "no_such_library_x": "x>=1"}) == {
        "nlopt": "hybridfit[nlopt]", "no_such_library_x": "x>=1"}
    assert optional.unavailable("it", {"numpy": "numpy"}) is None


def test_a_third_party_plugin_declares_its_own_requirement():
    class NeedsTorch(Plugin):
        requires = {"no_such_library_x": "no-such-library>=2"}

    with pytest.raises(MissingLibrary) as err:
        NeedsTorch()
    assert str(err.value) == ("plugin 'NeedsTorch' needs no_such_library_x, not installed: "
                              'pip install "no-such-library>=2"')


@pytest.mark.parametrize("name", sorted(OPTIONAL_PLUGINS))
def test_creating_a_plugin_without_its_library_is_one_line_naming_the_install(monkeypatch, name):
    library, extra = OPTIONAL_PLUGINS[name]
    _block(monkeypatch, library)
    with pytest.raises(MissingLibrary) as err:
        hybridfit.create("optimizer", name)
    assert str(err.value) == f'plugin {name!r} needs {library}, not installed: pip install "hybridfit[{extra}]"'
    with pytest.raises(MissingLibrary):  # a wrapper's inner optimiser too
        hybridfit.create("optimizer", "stepwise", {"optimizer": name}).inner


@pytest.mark.parametrize("name", sorted(OPTIONAL_PLUGINS))
def test_the_plugin_with_its_library_is_available(name):
    info = next(i for i in registry.available("optimizer") if i.name == name)
    assert info.error is None and info.unavailable is None


def test_plugins_lists_it_as_unavailable_with_the_install_line(monkeypatch, capsys):
    _block(monkeypatch, "nlopt")
    assert main(["plugins"]) == 0
    lines = {ln.split()[0]: ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("  ")}
    assert lines["nlopt"].endswith('UNAVAILABLE: plugin \'nlopt\' needs nlopt, not installed: '
                                   'pip install "hybridfit[nlopt]"')
    assert "UNAVAILABLE" not in lines["cmaes"] and "UNAVAILABLE" not in lines["pso"]


@pytest.fixture
def frames_file(tmp_path):
    data = hybridfit.synthetic_proposals(2, seed=3)
    np.savez(tmp_path / "frames.npz", **data)
    return tmp_path / "frames.npz"


def test_fit_with_it_exits_2_with_one_line_and_writes_nothing(monkeypatch, capsys, frames_file, tmp_path):
    _block(monkeypatch, "casadi")
    out = tmp_path / "fit.npz"
    assert main(["fit", str(frames_file), "--out", str(out), "--optimizer", "casadi-ik", "--budget", "200"]) == 2
    err = capsys.readouterr().err
    assert err == ("hybridfit: error: plugin 'casadi-ik' needs casadi, not installed: "
                   'pip install "hybridfit[casadi]"\n')
    assert not out.exists()


def test_a_study_with_it_exits_2_with_one_line(monkeypatch, capsys, tmp_path):
    from tests.study.conftest import TINY

    _block(monkeypatch, "pymoo")
    study = tmp_path / "tiny.toml"
    study.write_text(TINY.replace("[base]", '[base]\noptimizer = "pymoo"').replace(
        '"optimizer_config.schedule" = ["stepwise", "joint"]', ""))
    assert main(["study", str(study), "--quick", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(study) in err and 'pip install "hybridfit[pymoo]"' in err


def test_symbolic_kinematics_without_casadi(monkeypatch, hand26):
    from hybridfit.model.casadi import casadi_forward

    _block(monkeypatch, "casadi")
    with pytest.raises(MissingLibrary, match=r'hybridfit.model.casadi needs casadi, .*"hybridfit\[casadi\]"'):
        casadi_forward(hand26.kinematic_tree(), np.zeros(hand26.n_params))


def test_the_dask_executor_without_dask(monkeypatch):
    from hybridfit.study.executors import make_executor

    _block(monkeypatch, "distributed")
    with pytest.raises(MissingLibrary, match=r'the dask executor needs distributed, .*"hybridfit\[dask\]"'):
        make_executor("dask", jobs=1)


#: a fresh interpreter in which the optional libraries cannot be imported (a core-only
#: install): every module of the package imports, the default plugins fit, the optional
#: ones are listed as unavailable
CORE_ONLY = textwrap.dedent("""
    import importlib, pkgutil, sys
    BLOCKED = set(sys.argv[1].split(","))

    class Blocker:
        def find_spec(self, name, path=None, target=None):
            if name.partition(".")[0] in BLOCKED:
                raise ModuleNotFoundError(f"No module named {name!r} (blocked)", name=name)

    sys.meta_path.insert(0, Blocker())
    import hybridfit
    from hybridfit.cli import main

    def walk(package):
        for m in pkgutil.iter_modules(package.__path__, package.__name__ + "."):
            if m.name == "hybridfit.__main__":  # runs the command line
                continue
            module = importlib.import_module(m.name)
            if m.ispkg:
                walk(module)

    walk(hybridfit)
    codes = [main(["plugins"]), main(["synth", "proposals", "--frames", "2", "--seed", "3", "--out", "frames.npz"]),
             main(["fit", "frames.npz", "--budget", "300", "--out", "fit.npz"])]
    import json
    import numpy as np
    with np.load("fit.npz") as fits:  # the default schedule ran, its local stage too
        print("local stage", *(stage["optimizer"]["name"] for stage in json.loads(str(fits["schedule"]))[0]["stages"]
                               if stage["name"] == "local"))
    print("exit codes", *codes)
    print("imported", *sorted(n for n in BLOCKED if n in sys.modules))
""")


def test_a_core_only_install_fits_with_the_default_plugins_and_lists_the_others(tmp_path):
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1", "PYTHONWARNINGS": "ignore"}  # JIT off: no compile wait
    done = subprocess.run([sys.executable, "-c", CORE_ONLY, ",".join(OPTIONAL_LIBRARIES)], cwd=tmp_path, env=env,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    out = done.stdout.splitlines()
    assert out[-2:] == ["exit codes 0 0 0", "imported"], done.stdout
    assert "fitted 2/2 frames" in done.stdout and "local stage levenberg-marquardt" in out
    lines = {ln.split()[0]: ln for ln in out if ln.startswith("  ")}
    for name, (library, extra) in OPTIONAL_PLUGINS.items():
        assert lines[name].endswith(f'needs {library}, not installed: pip install "hybridfit[{extra}]"'), lines[name]
    for name in ("hand26", "hand27", "clamped-confidence", "clamped-then-soft-l1", "soft-l1", "pso", "stepwise",
                 "stepwise-pso", "levenberg-marquardt"):
        assert "UNAVAILABLE" not in lines[name] and "FAILED" not in lines[name]
