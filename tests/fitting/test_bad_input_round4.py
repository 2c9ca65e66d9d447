"""Bad input, round 4 (issue 39): the fit's run-time guards. A plugin's broken output (an
optimiser's NaN or out-of-bounds rows, a model's wrong joints or bounds) is a PluginError
naming the plugin where it enters the core, the frames finished before it kept; a bad
``*_config`` argument is one HybridfitError naming it; an unregistered model instance is
recorded so that it can be rebuilt, or its export says why not."""

from __future__ import annotations

import json
import pickle

import numpy as np
import pytest

import hybridfit
from hybridfit import registry, testing
from hybridfit.errors import HybridfitError, PluginError
from hybridfit.fitting import frames as fitting
from hybridfit.keys import stage_keys
from hybridfit.optimizer import BatchSteps, Optimizer
from hybridfit_plugins.optimizers.pso import PSO, STEPS


@pytest.fixture(scope="module")
def six():
    """6 frames, every point observed (one layout: frames of a chunk run as one group)."""
    return hybridfit.synthetic_proposals(6, k=2, p_missing=0.0, seed=4)


def _pso_asking(change, frames=None):
    """PSO whose asked rows pass through ``change(X)`` (a copy) in groups holding one of ``frames``
    (None: every group); one stage ("all"), seed 0."""
    broken = set()
    keys_of = None if frames is None else set(stage_keys(0, frames, 1)[:, 0].tolist())

    def init(start, lower, upper, keys, *args):
        state = STEPS.init(start, lower, upper, keys, *args)
        if keys_of is None or keys_of & set(keys.tolist()):
            broken.add(id(state[0]))
        return state

    def ask(state, m):
        X = STEPS.ask(state, m)
        return change(X.copy()) if id(state[0]) in broken else X

    class Broken(PSO):
        def batch_steps(self):
            return BatchSteps(init, ask, STEPS.tell)

    return Broken()


def _nan(X):
    X[0, 0, 3] = np.nan
    return X


def _beyond(X):
    X[:, :, -1] += 100.0  # far outside the last parameter's joint limit (radians)
    return X


@pytest.mark.parametrize("change, match", [(_nan, r"ask\(state, \d+\) returned NaN or inf"),
                                           (_beyond, r"ask\(state, \d+\) returned hypotheses outside the bounds "
                                                     r"of the stage \(its search box\): little_dip_flexion")],
                         ids=["nan", "outside"])
def test_an_optimizers_broken_rows_are_a_plugin_error_naming_it(six, change, match):
    with pytest.raises(PluginError, match=f"optimizer Broken: {match}"):
        hybridfit.fit(six["proposals"], six["confidences"], optimizer=_pso_asking(change), budget=300)


def test_the_frames_fitted_before_the_broken_rows_are_kept(six, monkeypatch):
    monkeypatch.setattr(fitting, "CHUNK", 2)
    with pytest.raises(PluginError, match="NaN or inf") as err:
        hybridfit.fit(six["proposals"], six["confidences"], optimizer=_pso_asking(_nan, frames=[2]), budget=300)
    partial = err.value.result
    assert partial.failed.tolist() == [False, False, True, True, True, True]
    assert np.isfinite(partial.params[:2]).all() and np.isnan(partial.params[2:]).all()
    assert partial.errors[2] == "not fitted: a plugin error stopped the run"


def test_the_chunks_running_beside_a_broken_one_are_kept(six, monkeypatch):
    """With jobs > 1 chunks run at once: the first one failing does not take the one beside it along."""
    monkeypatch.setattr(fitting, "CHUNK", 2)
    with pytest.raises(PluginError, match="NaN or inf") as err:
        hybridfit.fit(six["proposals"], six["confidences"], optimizer=_pso_asking(_nan, frames=[0]), budget=300,
                      jobs=2)
    assert err.value.result.failed.tolist() == [True, True, False, False, True, True]


class _OutsideCallback(Optimizer):
    """A callback solver whose task.evaluate gets rows beyond the box (or NaN)."""

    value = 1.0

    def minimize(self, task, rng):
        task.evaluate(np.vstack([task.x0, task.upper + type(self).value]))


@pytest.mark.parametrize("value, match", [(1.0, "outside the bounds of the stage"), (np.nan, "NaN or inf")])
def test_a_callback_solvers_broken_rows_are_a_plugin_error_too(six, value, match):
    broken = type("Outside", (_OutsideCallback,), {"value": value})()
    with pytest.raises(PluginError, match=f"optimizer Outside: task.evaluate was given .*{match}"):
        hybridfit.fit(six["proposals"][:1], six["confidences"][:1], optimizer=broken, budget=50)


# ------------------------------------------------------------------ models: broken output
class _Transposed(testing.ToyHand):
    def _forward(self, params):
        return np.ascontiguousarray(super()._forward(params).transpose(0, 2, 1))


class _Single(testing.ToyHand):
    def _forward(self, params):
        return super()._forward(params).astype(np.float32)


class _ShortBounds(testing.ToyHand):
    def bounds(self):
        lower, upper = super().bounds()
        return lower[:-1], upper[:-1]


class _SwappedBounds(testing.ToyHand):
    def bounds(self):
        lower, upper = super().bounds()
        return upper, lower


class _BadStage(testing.ToyHand):
    def stages(self):
        palm, a, b = super().stages()
        return palm, a, type(b)(b.name, b.parameters + (13,), b.joints)


@pytest.mark.parametrize("model, match", [
    (_Transposed(), r"model _Transposed: forward\(\(N, 13\)\) returned float64 \(1, 3, 7\), expected float64 "
                    r"\(1, 7, 3\)"),
    (_Single(), r"model _Single: forward\(\(N, 13\)\) returned float32 \(1, 7, 3\), expected float64"),
    (_ShortBounds(), r"model _ShortBounds: bounds\(\) gave arrays of shapes \(12,\) and \(12,\) .*expected two "
                     r"\(13,\)"),
    (_SwappedBounds(), r"model _SwappedBounds: bounds\(\) has lower > upper \(or NaN\) for 'x', 'y'"),
    (_BadStage(), r"model _BadStage: stage 'b' names parameter 13, beyond its 13 parameters"),
], ids=lambda v: type(v).__name__ if not isinstance(v, str) else "")
def test_a_models_broken_output_is_a_plugin_error_naming_it(model, match):
    data = hybridfit.synthetic_proposals(2, k=2, seed=1, model=testing.ToyHand())
    with pytest.raises(PluginError, match=match):
        hybridfit.fit(data["proposals"], data["confidences"], model=model, objective=testing.ToyClamped(),
                      optimizer="pso", budget=100)


# ------------------------------------------------------------------ the *_config arguments
@pytest.mark.parametrize("argument", ["model_config", "objective_config", "optimizer_config"])
@pytest.mark.parametrize("value, what", [([1, 2], "list"), ("scale = 2", "str"), ({1: 2}, "the setting name 1")])
def test_a_config_that_is_not_a_table_of_settings_is_refused_naming_the_argument(six, argument, value, what):
    with pytest.raises(HybridfitError, match=f"^{argument} must be a table of settings {{name: value}}.*{what}"):
        hybridfit.fit(six["proposals"], six["confidences"], budget=300, **{argument: value})


def _deep(n: int) -> dict:
    deep: dict = {}
    inner = deep
    for _ in range(n):
        inner["a"] = {}
        inner = inner["a"]
    return deep


def test_deeply_nested_settings_are_refused_in_one_line(six):
    """A setting that takes any table (stepwise's refine_config) took 5000 levels: the plugin then
    failed to pickle (RecursionError: fit's worker processes) and to print (repr)."""
    with pytest.raises(HybridfitError, match=r"^StepwisePSO settings: refine_config: nested more than 32 levels "
                                             r"deep$"):
        hybridfit.fit(six["proposals"], six["confidences"], budget=300, optimizer_config={"refine_config": _deep(5000)})
    for argument in ("model_config", "objective_config"):
        with pytest.raises(HybridfitError, match="nested more than 32 levels deep"):
            hybridfit.fit(six["proposals"], six["confidences"], budget=300, **{argument: {"a": _deep(100_000)}})
    with pytest.raises(HybridfitError, match="nested more than 32 levels deep"):
        registry.create("optimizer", "stepwise-pso", {"refine_config": _deep(32)})  # 33 tables
    deepest = registry.create("optimizer", "stepwise-pso", {"refine_config": _deep(31)})
    assert pickle.loads(pickle.dumps(deepest)) == deepest and repr(deepest) and json.dumps(deepest.get_params())


@pytest.mark.parametrize("argument, value", [("model", 3), ("objective", None), ("optimizer", testing.ToyHand())])
def test_a_plugin_argument_that_is_no_plugin_of_its_kind_is_refused(six, argument, value):
    with pytest.raises(HybridfitError, match=f"^{argument} must be a registered name or an? .* instance, got "):
        hybridfit.fit(six["proposals"], six["confidences"], budget=300, **{argument: value})


# ------------------------------------------------------------------ an unregistered model instance
class LongBones(testing.ToyHand):
    """An unregistered model class (no entry point)."""


def test_an_unregistered_model_instance_is_recorded_so_that_it_can_be_rebuilt(tmp_path):
    model = LongBones(bone_mm=35.0)
    data = hybridfit.synthetic_proposals(2, k=2, seed=2, model=model)
    fit = hybridfit.fit(data["proposals"], data["confidences"], model=model, objective=testing.ToyClamped(),
                        optimizer="pso", budget=100)
    assert fit.model == f"{__name__}:LongBones" and json.loads(fit.model_settings) == {"bone_mm": 35.0}
    assert fit.hand() == model  # its module is imported: rebuilt from the record
    np.savez(tmp_path / "fits.npz", **fit.to_npz())
    from hybridfit.exports.fitted import load_fitted

    assert load_fitted(tmp_path / "fits.npz").model == model


def test_an_unregistered_model_whose_module_is_not_imported_says_how_to_rebuild_it(tmp_path):
    with pytest.raises(HybridfitError, match=r"model 'some_lab.hands:LabHand' is a class that is not registered as a "
                                             r"plugin .*: import some_lab.hands first .* or register it"):
        registry.create("model", "some_lab.hands:LabHand", {})
    with pytest.raises(HybridfitError, match=r"names no HandModel"):
        registry.create("model", "json:JSONDecoder", {})


class _NanDerived(testing.ToyHand):
    @property
    def derived_points(self):
        return {"middle": {"a1": float("nan"), "b1": 0.5}}


def test_a_models_non_finite_derived_point_weight_is_a_plugin_error_naming_it():
    """(A user's NaN weight in hand26's settings is refused by the settings: tests/model/test_bad_settings.py.)"""
    data = hybridfit.synthetic_proposals(2, k=2, seed=1, model=testing.ToyHand())
    names = testing.ToyHand.joint_names[:-1] + ("middle",)
    with pytest.raises(PluginError, match="model _NanDerived: its derived points have NaN or inf joint weights"):
        hybridfit.fit(data["proposals"], data["confidences"], model=_NanDerived(), objective=testing.ToyClamped(),
                      optimizer="pso", budget=100, joint_names=names)


def test_an_unregistered_class_defined_in_a_script_or_a_function_says_it_cannot_be_found_again():
    for name, where in (("__main__:LabHand", r"in a script \(__main__\)"),
                        (f"{__name__}:f.<locals>.Hand", "inside a function")):
        with pytest.raises(HybridfitError, match=f"is a class defined {where}, not registered as a plugin, which "
                                                 "nothing can find again: define it at the top level of an importable "
                                                 "module"):
            registry.create("model", name, {})


def test_an_unregistered_class_its_imported_module_lacks_is_named():
    with pytest.raises(HybridfitError, match=f"module {__name__} has no class Renamed \\(renamed or removed"):
        registry.create("model", f"{__name__}:Renamed", {})
