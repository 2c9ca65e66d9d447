"""Plugin discovery through entry points: names, errors, broken plugins."""

from __future__ import annotations

import sys
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
