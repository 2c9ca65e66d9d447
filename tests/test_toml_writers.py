"""TOML writers (calibrate.to_toml, skeleton files) go through tomli_w and read back equal."""

import tomllib

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit.fitting.calibrate import to_toml
from hybridfit.datasets import skeletons

names = st.text(st.characters(codec="utf-8", exclude_categories=("Cs", "Cc")), min_size=1, max_size=12)
scalars = st.one_of(st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=False, allow_infinity=False), names)
values = st.one_of(scalars, st.lists(st.floats(-1e3, 1e3), max_size=3),
                   st.dictionaries(names, st.one_of(scalars, st.dictionaries(names, st.floats(-1e3, 1e3), max_size=3)),
                                   max_size=3))


@settings(max_examples=100, deadline=None)
@given(st.dictionaries(names, values, max_size=5))
def test_model_settings_read_back_equal(config):
    assert tomllib.loads(to_toml(config)) == config


def test_numpy_values_are_written_as_plain_numbers():
    config = {"scale": np.float64(1.05), "n": np.int64(3), "lengths": {"a": np.float32(2.5)}, "xs": np.arange(3.0)}
    assert tomllib.loads(to_toml(config)) == {"scale": 1.05, "n": 3, "lengths": {"a": 2.5}, "xs": [0.0, 1.0, 2.0]}


def test_hand26_settings_round_trip_into_an_equal_model():
    model = hybridfit.create("model", "hand26", {"mirror": True, "scale": 1.1})
    assert hybridfit.create("model", "hand26", tomllib.loads(to_toml(model.get_params()))) == model


def test_every_built_in_skeleton_reads_back_equal(tmp_path):
    for name in ("icvl", "nyu", "msra"):
        sk = skeletons.skeleton(name)
        path = tmp_path / f"{name}.toml"
        path.write_text(skeletons.to_toml(sk))
        again = skeletons.load_skeleton(path)
        assert (again.dataset, again.model, again.names, again.model_names, again.fingertips) == \
               (sk.dataset, sk.model, sk.names, sk.model_names, sk.fingertips)
        assert again.derived_weights == sk.derived_weights
