"""Plugin discovery through entry points: names, errors, broken plugins."""

from __future__ import annotations

import sys
import tomllib
import warnings

import pytest

import hybridfit
from hybridfit import registry
from hybridfit.errors import HybridfitError, PluginError, UnknownPluginError
from hybridfit.optional import MissingLibrary


def test_reference_plugins_are_registered():
    assert "hand26" in registry.names("model")
    assert "clamped-confidence" in registry.names("objective")
    assert {"pso", "stepwise-pso", "stepwise"} <= set(registry.names("optimizer"))


def test_unknown_name_lists_registered_names_and_closest_match():
    with pytest.raises(UnknownPluginError) as err:
        registry.get("optimizer", "stepwise-psp")
    message = str(err.value)
    assert "did you mean 'stepwise-pso'?" in message and "pso" in message and "registered optimizers" in message
    with pytest.raises(HybridfitError, match="unknown plugin kind"):
        registry.get("renderer", "x")


def test_create_from_name_config_or_instance():
    pso = registry.create("optimizer", "pso", {"particles": 10})
    assert pso.settings.particles == 10 and pso.name == "pso"
    assert registry.create("optimizer", pso) is pso
    assert registry.create("optimizer", pso, {"particles": 12}).settings.particles == 12


def test_settings_round_trip_and_repr():
    pso = registry.create("optimizer", "pso", {"particles": 10, "social": 1.5})
    assert type(pso)(**pso.get_params()) == pso
    assert repr(pso) == "PSO(particles=10, social=1.5)"


@pytest.fixture
def broken_distribution(tmp_path):
    """A fake installed distribution with one broken and one working plugin."""
    dist = tmp_path / "brokenplugins-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: brokenplugins\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(
        "[hybridfit.optimizers]\n"
        "broken-opt = brokenplugins_mod:Missing\n"
        "fine-opt = brokenplugins_mod:Fine\n"
        "[hybridfit.objectives]\n"
        "raising-obj = brokenplugins_raising:Objective\n"
        "needs-lib-obj = brokenplugins_needs:Objective\n"
    )
    (tmp_path / "brokenplugins_raising.py").write_text("raise ZeroDivisionError('broken at import')\n")
    (tmp_path / "brokenplugins_needs.py").write_text(
        "from hybridfit.optional import import_library\n"
        "import_library('no_such_library_x', 'no-such-library>=2', 'plugin needs-lib-obj')\n"
    )
    (tmp_path / "brokenplugins_mod.py").write_text(
        "from hybridfit_plugins.optimizers.pso import PSO\n"
        "class Fine(PSO):\n    '''A working third-party optimiser.'''\n"
    )
    sys.path.insert(0, str(tmp_path))
    registry.refresh()
    yield
    sys.path.remove(str(tmp_path))
    for module in ("brokenplugins_mod", "brokenplugins_raising", "brokenplugins_needs"):
        sys.modules.pop(module, None)
    registry.refresh()


def test_a_broken_plugin_warns_and_the_others_keep_working(broken_distribution):
    with pytest.warns(UserWarning, match=r"plugin 'broken-opt' \(hybridfit.optimizers = brokenplugins_mod:Missing\) failed"):
        infos = {i.name: i for i in registry.available("optimizer")}
    assert infos["broken-opt"].error and "Missing" in infos["broken-opt"].error
    assert infos["fine-opt"].error is None and infos["fine-opt"].distribution == "brokenplugins"
    assert infos["pso"].error is None
    with pytest.raises(PluginError, match=r"optimizer plugin 'broken-opt' \(hybridfit.optimizers = "
                                          r"brokenplugins_mod:Missing\) failed to import: AttributeError"):
        registry.get("optimizer", "broken-opt")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert registry.create("optimizer", "fine-opt").settings.particles is None


def test_a_plugin_whose_import_fails_is_a_plugin_error_naming_it_and_its_entry_point(broken_distribution):
    for get in (lambda: registry.get("objective", "raising-obj"), lambda: hybridfit.create("objective", "raising-obj")):
        with pytest.raises(PluginError, match=r"objective plugin 'raising-obj' \(hybridfit.objectives = "
                                              r"brokenplugins_raising:Objective\) failed to import: "
                                              r"ZeroDivisionError: broken at import") as err:
            get()
        assert not isinstance(err.value, HybridfitError)  # a bug of the plugin, not the user's input
    with pytest.raises(PluginError, match="optimizer plugin 'broken-opt'"):  # a wrapper's inner optimiser too
        hybridfit.create("optimizer", "stepwise", {"optimizer": "broken-opt"}).inner


def test_a_plugin_module_missing_its_optional_library_stays_a_user_error_with_the_install_line(broken_distribution):
    with pytest.raises(MissingLibrary, match=r'plugin needs-lib-obj needs no_such_library_x, not installed: '
                                             r'pip install "no-such-library>=2"'):
        registry.get("objective", "needs-lib-obj")
    with pytest.warns(UserWarning) as caught:  # the fixture's raising-obj warns; needs-lib-obj is no failure
        info = next(i for i in registry.available("objective") if i.name == "needs-lib-obj")
    assert not any("needs-lib-obj" in str(w.message) for w in caught)
    assert info.error is None and info.unavailable.endswith('pip install "no-such-library>=2"')


def test_the_registry_writes_no_names_onto_classes():
    pso = registry.get("optimizer", "pso")
    assert pso.name == "pso" and "name" not in pso.__dict__

    class MyPSO(pso):
        """An unregistered subclass."""

    assert MyPSO.name == "" and MyPSO().name == ""
    assert registry.create("optimizer", "pso").name == "pso"  # the registered class keeps its name
    assert registry.create("optimizer", "stepwise-pso").name == "stepwise-pso"  # a registered subclass has its own


def test_a_registered_subclass_of_a_registered_plugin_has_its_own_name(broken_distribution):
    fine = registry.get("optimizer", "fine-opt")
    assert fine.name == "fine-opt" and registry.get("optimizer", "pso").name == "pso"


def make_distribution(root, name: str, entry_points: str, modules: dict[str, str]):
    """A throwaway installed distribution ``name`` under ``root`` (a ``*.dist-info`` folder
    with its entry_points.txt, beside the plugin modules); put ``root`` on sys.path to install it."""
    dist = root / f"{name}-1.0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(entry_points)
    for module, text in modules.items():
        (root / f"{module}.py").write_text(text)


@pytest.fixture
def install(tmp_path):
    """install(name, entry_points, modules): a throwaway distribution first on sys.path, removed after."""
    roots, modules_made = [], []

    def install(name, entry_points, modules):
        root = tmp_path / name
        make_distribution(root, name, entry_points, modules)
        sys.path.insert(0, str(root))
        roots.append(str(root))
        modules_made.extend(modules)
        registry.refresh()

    yield install
    for root in roots:
        sys.path.remove(root)
    for module in modules_made:
        sys.modules.pop(module, None)
    registry.refresh()
    from hybridfit.study import cache

    cache.code_versions.cache_clear()


FINE_OPTIMIZER = ("from hybridfit_plugins.optimizers.pso import PSO\n"
                  "class Optimizer(PSO):\n    '''A third-party optimiser.'''\n")


def test_a_plugin_exiting_at_import_is_a_plugin_error_and_listed_as_broken(install, capsys):
    install("exitplugins", "[hybridfit.objectives]\nexit-obj = exitplugins_exit:Objective\n"
            "[hybridfit.optimizers]\nbase-opt = exitplugins_base:Optimizer\n", {
                "exitplugins_exit": "import sys\nsys.exit(3)\n",
                "exitplugins_base": "class Odd(BaseException):\n    pass\nraise Odd('odd')\n"})
    for get in (lambda: registry.get("objective", "exit-obj"), lambda: hybridfit.create("objective", "exit-obj")):
        with pytest.raises(PluginError, match=r"objective plugin 'exit-obj' \(hybridfit.objectives = "
                                              r"exitplugins_exit:Objective\) failed to import: SystemExit: 3"):
            get()
    with pytest.raises(PluginError, match=r"optimizer plugin 'base-opt' .* failed to import: Odd: odd"):
        registry.get("optimizer", "base-opt")
    from hybridfit.cli import main

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert main(["plugins"]) == 0
    assert {"exit-obj", "base-opt"} <= {w.message.args[0].split("'")[1] for w in caught}
    out = capsys.readouterr().out
    assert "hybridfit.optimizers:" in out and "pso" in out  # every group listed, after the broken one
    line = next(ln for ln in out.splitlines() if "exit-obj" in ln)
    assert "[exitplugins]" in line and "FAILED TO IMPORT (SystemExit: 3)" in line
    assert "FAILED TO IMPORT (Odd: odd)" in next(ln for ln in out.splitlines() if "base-opt" in ln)
    with warnings.catch_warnings():  # an unrelated use of plugins never imports it
        warnings.simplefilter("error")
        from hybridfit.study.cache import code_versions

        code_versions.cache_clear()
        assert "exitplugins" in code_versions()
        assert registry.create("objective", "clamped-confidence") is not None


def test_a_keyboard_interrupt_at_a_plugins_import_is_not_a_plugin_error(install):
    install("ctrlcplugins", "[hybridfit.objectives]\nctrlc-obj = ctrlcplugins_mod:Objective\n",
            {"ctrlcplugins_mod": "raise KeyboardInterrupt\n"})
    with pytest.raises(KeyboardInterrupt):
        registry.get("objective", "ctrlc-obj")


def test_a_third_party_plugin_cannot_take_a_built_ins_name(install, capsys):
    install("hijack", "[hybridfit.optimizers]\npso = hijack_mod:Optimizer\nhijack-opt = hijack_mod:Optimizer\n"
            "[hybridfit.models]\nhand26 = hijack_mod:Model\n", {"hijack_mod": FINE_OPTIMIZER + "Model = Optimizer\n"})
    builtin = "hybridfit_plugins.optimizers.pso"
    with pytest.warns(UserWarning, match=r"optimizer 'pso' is also registered by hijack \(hijack_mod:Optimizer\); "
                                         r"the built-in is used"):
        assert registry.get("optimizer", "pso").__module__ == builtin
    assert "hijack_mod" not in sys.modules
    with pytest.warns(UserWarning, match="hand26"):
        assert registry.get("model", "hand26").__module__ == "hybridfit_plugins.models.hand26"
    assert registry.names("optimizer").count("pso") == 1
    assert registry.get("optimizer", "hijack-opt").__module__ == "hijack_mod"  # its other names work
    from hybridfit.cli import main

    assert main(["plugins"]) == 0
    lines = capsys.readouterr().out.splitlines()
    pso = [ln for ln in lines if ln.split()[:1] == ["pso"]]
    assert len(pso) == 2 and "[hybridfit]" in pso[0]
    assert "[hijack]" in pso[1] and "CONFLICT" in pso[1] and "built-in" in pso[1]


def test_two_distributions_registering_one_name_are_refused_by_name(install):
    install("twina", "[hybridfit.optimizers]\ntwin-opt = twina_mod:Optimizer\n", {"twina_mod": FINE_OPTIMIZER})
    install("twinb", "[hybridfit.optimizers]\ntwin-opt = twinb_mod:Optimizer\n", {"twinb_mod": FINE_OPTIMIZER})
    assert "twin-opt" in registry.names("optimizer")
    with pytest.raises(HybridfitError, match=r"optimizer 'twin-opt' is registered by 2 distributions \(twin[ab] "
                                             r"\(twin[ab]_mod:Optimizer\), twin[ab] .*uninstall"):
        registry.get("optimizer", "twin-opt")
    assert "twina_mod" not in sys.modules and "twinb_mod" not in sys.modules


def test_plugins_are_imported_by_name_only_when_used(install, tmp_path, capsys):
    install("slowplugins", "[hybridfit.optimizers]\nslow-opt = slowplugins_slow:Optimizer\n"
            "[hybridfit.objectives]\nslow-obj = slowplugins_obj:Objective\n",
            {"slowplugins_slow": FINE_OPTIMIZER, "slowplugins_obj": "raise RuntimeError('imported')\n"})
    from hybridfit.cli import main
    from hybridfit.io import save_npz
    from hybridfit.study import parse_spec
    from hybridfit.study.cache import code_versions
    from tests.study.conftest import TINY

    assert {"slow-opt", "pso"} <= set(registry.names("optimizer"))
    for kind, name in (("model", "hand26"), ("objective", "clamped-confidence"), ("optimizer", "stepwise-pso")):
        registry.create(kind, name)
        registry.name_of(registry.get(kind, name))
    parse_spec(tomllib.loads(TINY), "tiny.toml")  # a study file's plugins are validated
    code_versions.cache_clear()
    assert "slowplugins" in code_versions()  # the distribution's code is in the cache keys, unimported
    save_npz(tmp_path / "p.npz", **hybridfit.synthetic_proposals(2, k=2, seed=1))
    assert main(["fit", str(tmp_path / "p.npz"), "--out", str(tmp_path / "f.npz"), "--budget", "200"]) == 0
    assert "slowplugins_slow" not in sys.modules
    with pytest.warns(UserWarning, match="slow-obj"):  # `hybridfit plugins` imports them all, to report on them
        assert main(["plugins"]) == 0
    assert "slowplugins_slow" in sys.modules and "slow-obj" in capsys.readouterr().out
