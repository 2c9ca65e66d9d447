"""Study files: validation errors name the file and field; the expansion is deterministic."""

from __future__ import annotations

import re

import pytest

from hybridfit.errors import HybridfitError
from hybridfit.study import expand, load_spec, parse_spec, trials

from .conftest import TINY, write


def error_of(tmp_path, text: str) -> str:
    path = write(tmp_path, text)
    with pytest.raises(HybridfitError) as err:
        load_spec(path)
    assert str(path) in str(err.value)
    return str(err.value)


@pytest.mark.parametrize("edit, expected", [
    (("[base]", "[base]\nbudgett = 3"), "base.budgett: unknown key"),
    (("budget = 400", 'budget = "lots"'), "base.budget"),
    (("[base]", '[base]\noptimizer = "psoo"'), "registered: "),
    (("[base]", '[base]\nobjective_config = { d_max = 3 }'), "objective_config"),
    (('kind = "synthetic-proposals"', 'kind = "webcam"'), "data: kind must be one of"),
    (("k = [1, 3]", 'k = [1, 5]'), "k: 5 exceeds data.k"),
    (('"optimizer_config.schedule" = ["stepwise", "joint"]', '"optimizer_config.schedule" = ["diagonal"]'),
     "sweep.grid (k=1, optimizer_config.schedule=diagonal): optimizer_config: StepwisePSO settings: schedule"),
    (("[sweep.grid]", "[sweep.grid]\nbudgets = [1]"), "sweep.grid.budgets: unknown setting"),
    (("[base]", '[base]\noptimizer = "stepwise"\noptimizer_config = { optimizer = "cmaess" }'),
     "unknown optimizer 'cmaess'; did you mean 'cmaes'?"),
    (("seeds = 2", "seeds = 0"), "seeds:"),
    (("[base]", '[report]\nmetrics = ["accuracy"]\n[base]'), "report.metrics.0: Input should be 'mean_error_mm'"),
    (("frames = 4", "frames = -4"), "data.frames: Input should be greater than or equal to 1"),
    (("frames = 4", "frames = 4\nforest = 3"), "data.forest: unknown key"),
])
def test_validation_errors_name_file_and_field(tmp_path, edit, expected):
    assert expected in error_of(tmp_path, TINY.replace(*edit))


def test_missing_data_file_is_named(tmp_path):
    text = TINY.replace('kind = "synthetic-proposals"\nframes = 4\nk = 3',
                        'kind = "proposals"\nfile = "nowhere.npz"')
    assert "data.file: no such file" in error_of(tmp_path, text)


def test_invalid_toml_names_file(tmp_path):
    assert "invalid TOML" in error_of(tmp_path, "name = \n")


def test_expansion_is_deterministic_with_derived_seeds(tiny_file):
    a, b = load_spec(tiny_file), load_spec(tiny_file)
    va, vb = expand(a), expand(b)
    assert [v.name for v in va] == [v.name for v in vb] == [
        "k=1, optimizer_config.schedule=stepwise", "k=1, optimizer_config.schedule=joint",
        "k=3, optimizer_config.schedule=stepwise", "k=3, optimizer_config.schedule=joint"]
    assert va[3].settings.k == 3 and va[3].settings.optimizer_settings == {"schedule": "joint"}
    seeds = a.seed_list()
    assert seeds == b.seed_list() and len(set(seeds)) == 2
    ta, tb = trials(a, va, "data"), trials(b, vb, "data")
    assert [t.key for t in ta] == [t.key for t in tb] and len({t.key for t in ta}) == 8
    assert {t.key for t in trials(a, va, "other data")}.isdisjoint(t.key for t in ta)


def test_variants_merge_into_base_and_quick_overrides(tmp_path):
    text = TINY.split("[sweep.grid]")[0] + """
[[sweep.variants]]
name = "joint"
optimizer_config = { schedule = "joint" }
budget = 900

[[sweep.variants]]
name = "stepwise"
"optimizer_config.stage_weights" = [4, 1, 1, 1, 1, 1]

[quick]
seeds = 1
base = { budget = 300 }
"""
    path = write(tmp_path, text)
    v = expand(load_spec(path))
    assert [x.name for x in v] == ["joint", "stepwise"]
    assert v[0].settings.budget == 900 and v[1].settings.budget == 400
    assert v[1].settings.optimizer_settings == {"stage_weights": [4, 1, 1, 1, 1, 1]}
    q = load_spec(path, quick=True)
    assert q.seed_list() == [q.seed_list()[0]] and expand(q)[1].settings.budget == 300


def test_shipped_studies_validate():
    from pathlib import Path

    for path in sorted((Path(__file__).parents[2] / "studies").glob("*.toml")):
        for quick in (False, True):
            assert expand(load_spec(path, quick=quick)), path


@pytest.mark.parametrize("raw, expected", [
    ({"data": {"kind": "synthetic-proposals", "framez": 3}}, "data.framez: unknown key (did you mean 'frames'?)"),
    ({"data": {"kind": "synthetic-depth", "forest": {"max_dept": 3}}},
     "data.forest.max_dept: unknown key (did you mean 'max_depth'?)"),
    ({"data": {"kind": "synthetic-proposals"}, "base": {"budgett": 3}}, "base.budgett: unknown key (did you mean 'budget'?)"),
])
def test_a_typo_names_the_closest_valid_key(raw, expected):
    with pytest.raises(HybridfitError, match=re.escape(expected)):
        parse_spec({"name": "typo", **raw}, "typo.toml")
