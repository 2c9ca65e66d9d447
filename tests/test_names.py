"""hybridfit.names: the Literal types that list the built-in plugins for editors are exactly the
entry points hybridfit's distribution declares, and they type hybridfit.fit's plugin arguments."""

from __future__ import annotations

import typing
from importlib.metadata import distribution

import pytest

import hybridfit
from hybridfit import names
from hybridfit.fitting.estimator import HybridEstimator
from hybridfit.fitting.tracking import track

KINDS = {"ModelName": "hybridfit.models", "ObjectiveName": "hybridfit.objectives",
         "OptimizerName": "hybridfit.optimizers"}


@pytest.mark.parametrize("alias, group", KINDS.items())
def test_each_literal_lists_exactly_the_built_in_entry_points(alias, group):
    declared = {ep.name for ep in distribution("hybridfit").entry_points if ep.group == group}
    listed = typing.get_args(getattr(names, alias))
    assert len(listed) == len(set(listed)) and set(listed) == declared


@pytest.mark.parametrize("function", [hybridfit.fit, track, HybridEstimator.__init__], ids=["fit", "track", "estimator"])
def test_the_plugin_arguments_offer_the_built_in_names_and_take_any_name_or_instance(function):
    local = {**vars(names), "HandModel": hybridfit.HandModel, "Objective": hybridfit.Objective,
             "Optimizer": hybridfit.Optimizer}
    hints = typing.get_type_hints(function, None, local)
    for argument, alias, base in (("model", "ModelName", hybridfit.HandModel),
                                  ("objective", "ObjectiveName", hybridfit.Objective),
                                  ("optimizer", "OptimizerName", hybridfit.Optimizer)):
        assert set(typing.get_args(hints[argument])) == {getattr(names, alias), str, base}, argument
