"""Skeletons as data: the built-in files map onto hand26, users' files round-trip, bad files
give one-line errors naming the file and key."""

from __future__ import annotations

import copy
import string
import tomllib

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit.cli import main
from hybridfit.datasets import SKELETONS, convention, skeleton
from hybridfit.datasets.results import read_xyz, write_xyz
from hybridfit.datasets.skeletons import NYU14, NYU36, check_model, load_skeleton, to_toml, with_derived_points

from .conftest import hand_points

SIZES = {"icvl": 16, "nyu": 14, "nyu36": 36, "msra": 21, "mediapipe": 21, "mano": 21}
JOINTS = hybridfit.create("model", "hand26").joint_names
TIPS = {"thumb_tip", "index_tip", "middle_tip", "ring_tip", "little_tip"}


def test_the_built_in_skeletons():
    assert {n: len(s) for n, s in SKELETONS.items()} == SIZES


@pytest.mark.parametrize("dataset", sorted(SIZES))
def test_every_point_maps_onto_the_model(dataset):
    sk = skeleton(dataset)
    check_model(sk)
    J = SIZES[dataset]
    assert len(sk.names) == len(sk.model_names) == len(set(sk.model_names)) == J
    model = hybridfit.create("model", "hand26", with_derived_points({}, dataset))
    M = model.point_matrix(sk.model_names)
    assert M.shape == (J, 21)
    assert abs(M.sum(axis=1) - 1).max() < 1e-9  # affine combinations: rigid motions carry over


@pytest.mark.parametrize("dataset", sorted(SIZES))
def test_fingertips_are_the_five_tips(dataset):
    sk = skeleton(dataset)
    assert {sk.model_names[t] for t in sk.fingertips} == TIPS and len(sk.fingertips) == 5


def test_a_derived_point_means_the_same_in_every_skeleton():
    seen: dict[str, dict[str, float]] = {}
    for sk in SKELETONS.values():
        for name, weights in sk.derived.items():
            assert seen.setdefault(name, weights) == weights, name


def test_nyu14_is_the_subset_of_nyu36():
    nyu, nyu36 = skeleton("nyu"), skeleton("nyu36")
    assert NYU36 == nyu36.names and NYU36[0] == "F1_KNU3_A" and NYU36[-1] == "PALM_6"
    assert NYU14 == (0, 3, 6, 9, 12, 15, 18, 21, 24, 25, 27, 30, 31, 32)
    assert nyu.model_names == tuple(nyu36.model_names[i] for i in NYU14)
    assert all(nyu36.derived[n] == w for n, w in nyu.derived.items())


def test_nyu36_finger_points_run_from_the_tip_to_the_base():
    """On straight fingers, each finger's six points (KNU3_A .. KNU1_B) come ever closer to
    its base, the A points strictly between their B points."""
    sk = skeleton("nyu36")
    model = hybridfit.create("model", "hand26", with_derived_points({}, "nyu36"))
    params = model.default_params()[None].copy()
    params[:, 7:] = 0.0
    pts = model.points(params, sk.model_names)[0]
    for f in range(5):
        finger = pts[6 * f:6 * f + 6]
        d = np.linalg.norm(finger - finger[-1], axis=-1)
        assert (np.diff(d) < -1.0).all(), (sk.names[6 * f], d)


def test_mano_is_manopths_order():
    """manopth's ManoLayer: MANO's 16 joints + 5 tip vertices, reordered for display."""
    raw = ["wrist"] + [f"{f}_{j}" for f in ("index", "middle", "little", "ring", "thumb")
                       for j in (("cmc", "mcp", "ip") if f == "thumb" else ("mcp", "pip", "dip"))]
    raw += [f"{f}_tip" for f in ("thumb", "index", "middle", "ring", "little")]
    reorder = [0, 13, 14, 15, 16, 1, 2, 3, 17, 4, 5, 6, 18, 10, 11, 12, 19, 7, 8, 9, 20]
    assert skeleton("mano").model_names == tuple(raw[i] for i in reorder) == skeleton("mediapipe").model_names


def test_names_are_case_blind_and_unknown_names_suggest_the_closest():
    assert skeleton("ICVL") is skeleton("icvl")
    with pytest.raises(hybridfit.HybridfitError, match=r"unknown dataset 'nyu3' \(did you mean 'nyu36'\?\)"):
        skeleton("nyu3")


def test_conventions_come_from_the_skeleton(tmp_path):
    assert convention("nyu36") is convention("nyu")
    with pytest.raises(hybridfit.HybridfitError, match="mediapipe skeleton names no camera convention"):
        convention("mediapipe")
    mine = tmp_path / "mine.toml"
    mine.write_text(to_toml(skeleton("msra")).replace('convention = "msra"', 'convention = "icvl"'))
    assert convention(str(mine)) is convention("icvl")


@pytest.mark.parametrize("dataset", sorted(SIZES))
def test_a_written_skeleton_reads_back_equal(tmp_path, dataset):
    path = tmp_path / "mine.toml"
    path.write_text(to_toml(skeleton(dataset)))
    got, want = skeleton(str(path)), skeleton(dataset)
    assert (got.dataset, got.names, got.model_names, got.fingertips, got.derived, got.convention, got.model) == \
        (want.dataset, want.names, want.model_names, want.fingertips, want.derived, want.convention, want.model)
    assert got.source == str(path)


_name = st.text(string.ascii_letters + string.digits + "_-. ", min_size=1, max_size=8)


@st.composite
def user_skeletons(draw):
    """(toml text, the dict it holds): random point names onto distinct hand26 joints or
    derived points with weights that sum to 1."""
    names = draw(st.lists(_name, min_size=1, max_size=8, unique=True))
    joints = draw(st.permutations(JOINTS))
    points, derived = {}, {}
    for i, n in enumerate(names):
        if draw(st.booleans()):
            support = draw(st.lists(st.sampled_from(JOINTS), min_size=1, max_size=4, unique=True))
            w = draw(st.lists(st.integers(-4, 8), min_size=len(support), max_size=len(support)))
            w[-1] = 8 - sum(w[:-1])
            assume(-8 <= w[-1] <= 16)  # weights within DERIVED_WEIGHT_RANGE [-1, 2]
            derived[f"d{i}"] = {j: v / 8 for j, v in zip(support, w)}
            points[n] = f"d{i}"
        else:
            points[n] = joints[i]
    tips = draw(st.lists(st.sampled_from(names), unique=True, max_size=5))
    raw = {"name": "mine", "model": "hand26", "fingertips": tips, "points": points, "derived": derived}
    return raw


def _value(v) -> str:
    """A Python value as a TOML value (strings, numbers, booleans, arrays, inline tables)."""
    import json

    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return {"nan": "nan", "inf": "inf", "-inf": "-inf"}.get(repr(v), repr(v))
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_value(x)}" for k, x in v.items()) + "}"
    return json.dumps(v) if isinstance(v, str) else str(v)


def _text(raw) -> str:
    """A dict of a skeleton file's shape as TOML: top-level tables of values or of tables."""
    import json

    lines, tables = [], []
    for k, v in raw.items():
        (tables if isinstance(v, dict) else lines).append((k, v))
    lines = [f"{json.dumps(k)} = {_value(v)}" for k, v in lines]
    for k, v in tables:
        lines.append(f"[{json.dumps(k)}]")
        lines += [f"{json.dumps(kk)} = {_value(vv)}" for kk, vv in v.items() if not isinstance(vv, dict)]
        for kk, vv in v.items():
            if isinstance(vv, dict):
                lines.append(f"[{json.dumps(k)}.{json.dumps(kk)}]")
                lines += [f"{json.dumps(j)} = {_value(w)}" for j, w in vv.items()]
    return "\n".join(lines) + "\n"


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(raw=user_skeletons())
def test_users_skeletons_round_trip(tmp_path, raw):
    path = tmp_path / "user.toml"
    path.write_text(_text(raw))
    sk = load_skeleton(path)
    assert sk.names == tuple(raw["points"]) and sk.model_names == tuple(raw["points"].values())
    assert [sk.names[i] for i in sk.fingertips] == raw["fingertips"] and sk.derived == raw["derived"]
    path.write_text(to_toml(sk))
    again = load_skeleton(path)
    assert (again.names, again.model_names, again.fingertips, again.derived) == \
        (sk.names, sk.model_names, sk.fingertips, sk.derived)
    model = hybridfit.create("model", "hand26", with_derived_points({}, str(path)))
    assert abs(model.point_matrix(sk.model_names).sum(axis=1) - 1).max() < 1e-9


VALID = tomllib.loads(to_toml(skeleton("icvl")))

# (mutation of the valid icvl file, the key the error must name, a pattern it must contain)
BREAKS = [
    (lambda r: r.pop("points"), "points", "missing or empty"),
    (lambda r: r.pop("fingertips"), "fingertips", "must be a list"),
    (lambda r: r.__setitem__("fingertip", r.pop("fingertips")), "fingertip", "did you mean 'fingertips'"),
    (lambda r: r.__setitem__("modle", "hand26"), "modle", "did you mean 'model'"),
    (lambda r: r.__setitem__("model", "hnad26"), "model", "did you mean 'hand26'"),
    (lambda r: r.__setitem__("convention", "nyy"), "convention", "did you mean 'nyu'"),
    (lambda r: r.__setitem__("name", 3), "name", "non-empty string"),
    (lambda r: r["points"].__setitem__("thumb_tip", "thumb_tp"), "points.thumb_tip", "did you mean 'thumb_tip'"),
    (lambda r: r["points"].__setitem__("index_tip", 7), "points.index_tip", "a string"),
    (lambda r: r["points"].__setitem__("index_tip", "thumb_tip"), "points.index_tip", "like points.thumb_tip"),
    (lambda r: r["points"].__setitem__("palm", "icvl_plam"), "derived.icvl_palm", "not used by any point"),
    (lambda r: r["derived"]["icvl_palm"].__setitem__("wirst", r["derived"]["icvl_palm"].pop("wrist")),
     "derived.icvl_palm.wirst", "did you mean 'wrist'"),
    (lambda r: r["derived"]["icvl_palm"].__setitem__("wrist", 0.5), "derived.icvl_palm", "must sum to 1"),
    (lambda r: r["derived"]["icvl_palm"].__setitem__("wrist", "0.4"), "derived.icvl_palm.wrist", "finite number"),
    (lambda r: r["derived"]["icvl_palm"].update(wrist=5.4, index_mcp=-4.85), "derived.icvl_palm.wrist",
     "outside [-1, 2]"),  # they still sum to 1
    (lambda r: r["derived"].__setitem__("icvl_palm", {}), "derived.icvl_palm", "non-empty table"),
    (lambda r: r.__setitem__("derived", {"wrist": {"wrist": 1.0}, **r["derived"]}), "derived.wrist",
     "not used by any point"),
    (lambda r: r["fingertips"].__setitem__(0, "thumb_tp"), "fingertips[0]", "did you mean 'thumb_tip'"),
    (lambda r: r["fingertips"].append("index_tip"), "fingertips", "twice"),
]


@pytest.mark.parametrize("i", range(len(BREAKS)))
def test_each_bad_key_is_named(tmp_path, i):
    raw = copy.deepcopy(VALID)
    mutate, key, pattern = BREAKS[i]
    mutate(raw)
    path = tmp_path / "bad.toml"
    path.write_text(_text(raw))
    with pytest.raises(hybridfit.HybridfitError) as err:
        skeleton(str(path))
    msg = str(err.value)
    assert msg.startswith(f"{path}: {key}: ") and pattern in msg and "\n" not in msg, msg


_leaves = st.one_of(st.booleans(), st.integers(), st.integers(10**308, 10**400), st.floats(), st.text(max_size=6))
_values = st.one_of(_leaves, st.lists(_leaves, max_size=3), st.dictionaries(st.text(max_size=4), _leaves, max_size=3))
_keys = st.text(max_size=6) | st.sampled_from(["name", "model", "convention", "fingertips", "points", "derived", "a\nb"])


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(where=st.sampled_from(["top", "points", "derived", "weights", "fingertips"]), key=_keys, value=_values,
       drop=st.booleans())
def test_generated_bad_files_give_one_line(tmp_path, where, key, value, drop):
    """Any key set to any value (or dropped) at any level: loads, or one line naming the file."""
    raw = copy.deepcopy(VALID)
    table = {"top": raw, "points": raw["points"], "derived": raw["derived"],
             "weights": raw["derived"]["icvl_palm"], "fingertips": None}[where]
    if table is None:
        raw["fingertips"] = [value] if drop else raw["fingertips"] + [value]
    elif drop and table:
        table.pop(key if key in table else next(iter(table)))
    else:
        table[key] = value
    path = tmp_path / "gen.toml"
    path.write_text(_text(raw))
    try:
        skeleton(str(path))
    except hybridfit.HybridfitError as err:
        assert str(err).startswith(f"{path}: ") and "\n" not in str(err), str(err)


def test_a_derived_point_with_a_joints_name_is_refused(tmp_path):
    raw = copy.deepcopy(VALID)
    raw["points"]["palm"], raw["derived"] = "wrist", {"wrist": {"index_mcp": 1.0}}
    path = tmp_path / "bad.toml"
    path.write_text(_text(raw))
    with pytest.raises(hybridfit.HybridfitError, match=r"bad.toml: derived.wrist: has the name of a hand26 joint"):
        skeleton(str(path))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(1, 2000), junk=st.binary(min_size=1, max_size=20))
def test_corrupt_files_give_one_line(tmp_path, cut, junk):
    """Truncated or garbled skeleton files: one line naming the file, never a traceback."""
    text = to_toml(skeleton("nyu")).encode()
    path = tmp_path / "bad.toml"
    path.write_bytes(text[:cut % len(text)] + junk)
    try:
        skeleton(str(path))
    except hybridfit.HybridfitError as err:
        assert str(err).startswith(f"{path}: ") and "\n" not in str(err)


def test_missing_file(tmp_path):
    with pytest.raises(hybridfit.HybridfitError, match=r"nope\.toml: no such skeleton file"):
        skeleton(str(tmp_path / "nope.toml"))


def test_a_users_file_is_read_again_when_it_changes(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text(to_toml(skeleton("msra")))
    assert len(skeleton(str(path))) == 21
    path.write_text(to_toml(skeleton("icvl")) + "\n# edited\n")
    assert len(skeleton(str(path))) == 16


def test_the_cli_takes_a_skeleton_file(tmp_path, capsys):
    """from-results, fit, evaluate and export with --dataset my.toml: ICVL's points renamed."""
    mine = tmp_path / "mine.toml"
    mine.write_text(to_toml(skeleton("icvl")).replace("_root =", "_base =").replace('"thumb_root"', '"thumb_base"'))
    truth = hand_points("icvl", 3)
    write_xyz(tmp_path / "r.txt", truth, str(mine))
    p, fits, out = tmp_path / "p.npz", tmp_path / "fits.npz", tmp_path / "out.txt"
    assert main(["proposals", "from-results", "--dataset", str(mine), str(tmp_path / "r.txt"), "--out", str(p)]) == 0
    assert main(["fit", str(p), "--dataset", str(mine), "--budget", "300", "--out", str(fits)]) == 0
    assert main(["export-results", str(fits), "--dataset", str(mine), "--out", str(out)]) == 0
    assert np.nanmean(np.linalg.norm(read_xyz(out, str(mine)) - truth, axis=-1)) < 30
    capsys.readouterr()
    bad = tmp_path / "bad.toml"
    bad.write_text(mine.read_text().replace('"index_mcp"', '"index_mpc"'))
    assert main(["fit", str(p), "--dataset", str(bad), "--out", str(tmp_path / "f2.npz")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"{bad}: points.index_base: unknown hand26 point 'index_mpc'" in err
    assert "did you mean 'index_mcp'" in err and not (tmp_path / "f2.npz").exists()


def test_config_keeps_its_own_derived_points():
    cfg = with_derived_points({"derived_points": {"icvl_palm": {"wrist": 1.0}}, "scale": 0.9}, "icvl")
    assert cfg["derived_points"]["icvl_palm"] == {"wrist": 1.0} and cfg["scale"] == 0.9


def test_hand26_refuses_bad_derived_points():
    with pytest.raises(hybridfit.HybridfitError, match="unknown joint 'elbow'"):
        hybridfit.create("model", "hand26", {"derived_points": {"p": {"elbow": 1.0}}})
    with pytest.raises(hybridfit.HybridfitError, match="has the name of a joint"):
        hybridfit.create("model", "hand26", {"derived_points": {"wrist": {"index_mcp": 1.0}}})


def test_a_study_takes_a_skeleton_file_relative_to_it(tmp_path):
    from hybridfit.study import load_spec

    (tmp_path / "skel").mkdir()
    (tmp_path / "skel" / "mine.toml").write_text(to_toml(skeleton("icvl")))
    write_xyz(tmp_path / "r.txt", hand_points("icvl", 2), "icvl")
    study = tmp_path / "s.toml"
    text = 'name = "s"\n[data]\nkind = "proposals"\nfile = "r.txt"\ndataset = "skel/mine.toml"\n'
    study.write_text(text)
    assert load_spec(study).data.dataset == str(tmp_path / "skel" / "mine.toml")
    study.write_text(text.replace("mine.toml", "mien.toml"))
    with pytest.raises(hybridfit.HybridfitError, match=r"s.toml: data.dataset: .*mien.toml: no such skeleton file"):
        load_spec(study)
    study.write_text(text.replace("skel/mine.toml", "nyu37"))
    with pytest.raises(hybridfit.HybridfitError, match=r"data.dataset: unknown dataset 'nyu37' \(did you mean"):
        load_spec(study)


def test_the_docs_example_is_a_valid_skeleton(tmp_path):
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "conventions.md").read_text()
    text = text[text.index("## Your own skeleton"):]
    (tmp_path / "example.toml").write_text(re.search(r"```toml\n(.*?)```", text, re.S).group(1))
    sk = skeleton(str(tmp_path / "example.toml"))
    assert sk.dataset == "mydata" and sk.derived == {"my_palm": {"wrist": 0.5, "middle_mcp": 0.5}}


def test_a_studys_data_key_follows_its_skeleton_files_content(tmp_path):
    from hybridfit.study import load_spec
    from hybridfit.study.cache import Cache
    from hybridfit.study.data import StudyData

    write_xyz(tmp_path / "r.txt", hand_points("icvl", 2), "icvl")
    skel = tmp_path / "a.toml"
    skel.write_text(to_toml(skeleton("icvl")))
    study = tmp_path / "s.toml"

    def key(name):
        study.write_text(f'name = "s"\n[data]\nkind = "proposals"\nfile = "r.txt"\ndataset = "{name}"\n')
        return StudyData(load_spec(study).data, Cache(tmp_path / "cache")).key

    first = key("a.toml")
    (tmp_path / "b.toml").write_text(skel.read_text())
    assert key("b.toml") == first  # moved: same content, same data
    skel.write_text(skel.read_text().replace("wrist = 0.4", "wrist = 0.6").replace("index_mcp = 0.15", "index_mcp = -0.05"))
    assert key("a.toml") != first


def test_fit_settings_name_the_points_and_the_file():
    from hybridfit.datasets.skeletons import fit_settings

    names, config = fit_settings(None, 16, "icvl", "hand26", {}, "p.npz")
    assert names == list(skeleton("icvl").model_names) and "icvl_palm" in config["derived_points"]
    assert fit_settings(None, 21, None, "hand26", {}, "p.npz") == (None, {})
    with pytest.raises(hybridfit.HybridfitError, match=r"^p\.npz: 15 points, but the icvl skeleton has 16$"):
        fit_settings(None, 15, "icvl", "hand26", {}, "p.npz")
    with pytest.raises(hybridfit.HybridfitError, match=r"^p\.npz: model hand26 lacks 1 of the 2 points to fit: 'elbow' "):
        fit_settings(["wrist", "elbow"], 2, None, "hand26", {}, "p.npz")
