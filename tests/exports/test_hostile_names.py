"""Generated hostile names (markup, spreadsheet formulas, control characters, ``$``, bytes
that are not UTF-8) in every writer of exports, the viewer and the plots: each name is
either refused where it is read, in one line naming the file (or model) and field, or
written inert: JSON that parses and gives the names back, CSV without a formula cell, BVH
that parses with the names given, HTML whose tags are the page's own, a plot drawn.

The writers are called in-process, a few examples each (derandomised)."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import tempfile
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit.errors import HybridfitError
from hybridfit.exports import export
from hybridfit.exports.bvh import write_bvh
from hybridfit.exports.fitted import load_fitted
from hybridfit.exports.viewer import write_view
from hybridfit.fitting.angles import PARAMETER_NAME, POSE_COLUMNS
from hybridfit.text import control_characters, csv_cell

from ._fits import make_fits
from .test_bvh import parse_bvh

FEW = settings(max_examples=12, deadline=None, database=None, derandomize=True,
               suppress_health_check=list(HealthCheck))

#: pieces of hostile names, joined at random with a little random text
PIECES = ["<script>alert(1)</script>", "</script>", "<img src=x onerror=alert(1)>", "<!--", "&amp;", '"', "'",
          "=cmd|' /C calc'!A0", "=1+1", "@SUM(A1)", "+1", "-2", "\t", "\r", "\n", "\x00", "\x1b[31m", "\u202e",
          "$", "$x^2$", "$5 vs $10", "\udcff", "\ud800", "{", "}", "[a](javascript:x)", ",", " ", "é", "手", "_"]
names = st.lists(st.one_of(st.sampled_from(PIECES), st.text(max_size=3)), min_size=1, max_size=4).map("".join)


def file_name(name: str) -> bool:
    """Whether a file system can hold ``name`` (from os.fsdecode, whose surrogates stand for bytes)."""
    try:
        raw = os.fsencode(name)
    except UnicodeEncodeError:
        return False
    return 0 < len(raw) < 200 and b"/" not in raw and b"\x00" not in raw and name not in (".", "..")


file_names = names.filter(file_name)


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    root = tmp_path_factory.mktemp("hostile")
    arrays = make_fits(root / "fits.npz", frames=2, failed=(1,))
    return root / "fits.npz", arrays


def as_stored(values) -> list[str]:
    """The names as an npz holds them (numpy drops trailing NULs)."""
    return [str(n) for n in np.asarray(values)]


def refused_in_one_line(err: HybridfitError, *words: str) -> None:
    message = str(err)
    assert "\n" not in message and all(w in message for w in words), message


# ------------------------------------------------------------------------ names from a fits file


@FEW
@given(st.dictionaries(st.integers(0, 20), names, min_size=1, max_size=3))
@example({3: "<script>alert(1)</script>", 5: "=cmd|' /C calc'!A0", 8: "cost_$5_vs_$10"})
@example({2: "a\x1b[31mb"})
@example({2: "f\udcff"})
@example({2: "wrist"})
def test_generated_joint_names_in_a_fits_file_give_json_that_round_trips(good, changes):
    path, arrays = good
    joint_names = as_stored([changes.get(i, n) for i, n in enumerate(arrays["joint_names"].tolist())])
    with tempfile.TemporaryDirectory() as tmp:
        fits = Path(tmp) / "fits.npz"
        np.savez(fits, **{**arrays, "joint_names": np.asarray(joint_names)})
        bad = len(set(joint_names)) < len(joint_names) or any(control_characters(n) for n in joint_names)
        try:
            export(fits, Path(tmp) / "hand.json")
        except HybridfitError as err:
            assert bad, err
            refused_in_one_line(err, str(fits), "joint_names")
            return
        assert not bad
        doc = json.loads((Path(tmp) / "hand.json").read_text(encoding="utf-8"))
        assert doc["joint_names"] == joint_names
        assert all(list(frame["joints_mm"]) == joint_names for frame in doc["frames"])


@FEW
@given(st.dictionaries(st.integers(7, 26), names, min_size=1, max_size=3))
@example({9: "=cmd|/Ccalc!A0", 10: "@SUM(A1)", 11: "-2+3", 12: "$5_vs_$10"})
@example({9: "a\x00b"})
@example({9: "\udcff"})
@example({9: "<script>alert(1)</script>"})
def test_generated_parameter_names_give_a_csv_without_formulas(good, changes):
    path, arrays = good
    parameter_names = as_stored([changes.get(i, n) for i, n in enumerate(arrays["parameter_names"].tolist())])
    with tempfile.TemporaryDirectory() as tmp:
        fits, out = Path(tmp) / "fits.npz", Path(tmp) / "angles.csv"
        np.savez(fits, **{**arrays, "parameter_names": np.asarray(parameter_names)})
        bad = (len(set(parameter_names)) < len(parameter_names) or any(control_characters(n) for n in parameter_names)
               or not all(PARAMETER_NAME.fullmatch(n) for n in parameter_names))
        try:
            export(fits, out)
        except HybridfitError as err:
            assert bad, err
            refused_in_one_line(err, str(fits), "parameter")
            return
        assert not bad
        import csv

        with open(out, newline="", encoding="utf-8") as fh:
            header = next(csv.reader(fh))
        assert header == [*POSE_COLUMNS, *(csv_cell(f"{n}_deg") for n in parameter_names[7:])]
        assert not any(cell[:1] in "=+-@\t\r" for cell in header)


# ------------------------------------------------------------------------ names from a model plugin


def hostile_model(joint_names: list[str]):
    hand26 = type(hybridfit.create("model", "hand26"))
    return type("Hostile", (hand26,), {"joint_names": tuple(joint_names), "name": "hostile"})()


@FEW
@given(st.dictionaries(st.integers(0, 20), names, min_size=1, max_size=3))
@example({3: "<script>alert(1)</script>", 5: "=1+1", 8: "$x$", 9: "{", 10: "}"})
@example({3: "a b", 4: "a_b"})
@example({3: "a\x00b"})
@example({3: "\udcff"})
def test_generated_model_joint_names_give_a_bvh_that_parses(good, changes):
    path, arrays = good
    joint_names = [changes.get(i, n) for i, n in enumerate(arrays["joint_names"].tolist())]
    fitted = dataclasses.replace(load_fitted(path), model=hostile_model(joint_names))
    bvh_names = [re.sub(r"\s+", "_", n) for n in joint_names]
    bad = (any(control_characters(n) for n in joint_names) or len(set(bvh_names)) < len(bvh_names)
           or not all(bvh_names))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "hand.bvh"
        try:
            write_bvh(out, fitted)
        except HybridfitError as err:
            assert bad, err
            refused_in_one_line(err, "model hostile")
            assert not out.exists()
            return
        assert not bad
        joints, frame_time, motion = parse_bvh(out.read_text(encoding="utf-8"))
        assert sorted(j[0] for j in joints) == sorted(bvh_names) and len(motion) == 2


class Tags(HTMLParser):
    """The start and end tags of a page, in order."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[str] = []

    def handle_starttag(self, tag, attrs) -> None:
        self.tags.append(tag)

    def handle_endtag(self, tag) -> None:
        self.tags.append("/" + tag)


def tags(text: str) -> list[str]:
    parser = Tags()
    parser.feed(text)
    return parser.tags


@FEW
@given(st.dictionaries(st.integers(0, 20), names, min_size=1, max_size=3), file_names)
@example({3: "</script><script>alert(1)</script>", 4: "<!--", 5: "\x00\n\udcff"}, "f\udcff<b>$5_vs_$10<!--.npz")
def test_generated_names_in_the_viewer_are_inert(good, changes, name):
    path, arrays = good
    joint_names = [changes.get(i, n) for i, n in enumerate(arrays["joint_names"].tolist())]
    with tempfile.TemporaryDirectory() as tmp:
        baseline = Path(tmp) / "plain.html"
        write_view(baseline, load_fitted(path))
        fits = Path(tmp) / name
        fits.write_bytes(path.read_bytes())
        fitted = dataclasses.replace(load_fitted(fits), model=hostile_model(joint_names))
        out = Path(tmp) / "hand.html"
        write_view(out, fitted)
        text = out.read_bytes().decode("utf-8")
        assert tags(text) == tags(baseline.read_text(encoding="utf-8"))  # no tag of a name's own
        data = re.search(r'<script type="application/json" id="hand-data">(.*?)</script>', text, re.S).group(1)
        page = json.loads(data)
        assert page["names"] == joint_names and page["source"] == name


@FEW
@given(file_names)
@example("cost_$5_vs_$10\udcff<script>.npz")
def test_generated_file_names_export_as_json_bvh_and_csv(good, name):
    path, arrays = good
    with tempfile.TemporaryDirectory() as tmp:
        fits = Path(tmp) / name
        fits.write_bytes(path.read_bytes())
        for ext in (".json", ".bvh", ".csv"):
            out = Path(tmp) / f"{name}{ext}"
            assert export(fits, out).frames == 2
            out.read_bytes().decode("utf-8")


# ------------------------------------------------------------------------ plots


@FEW
@given(st.lists(names, min_size=1, max_size=3))
@example(["cost_$5_vs_$10.npz", "f\udcff.npz", "<b>\x00</b>\n=1+1"])
def test_generated_labels_plot(labels):
    from hybridfit.cli.evaluate import plot_success
    from hybridfit.metrics import SUCCESS_THRESHOLDS_MM

    curve = np.linspace(0, 1, len(SUCCESS_THRESHOLDS_MM))
    with tempfile.TemporaryDirectory() as tmp:
        plot_success([(label, curve) for label in labels], str(Path(tmp) / "s.png"), labels[0])
        assert (Path(tmp) / "s.png").stat().st_size > 1000


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    from hybridfit.cli import main

    out = tmp_path_factory.mktemp("hostile-show") / "seq"
    assert main(["synth", "test", "--out", str(out), "--frames", "1"]) == 0
    return out


@settings(FEW, max_examples=6)
@given(file_names)
@example("seq_$5_vs_$10\udcff")
def test_show_draws_generated_folder_names(dataset, capsys, name):
    from hybridfit.cli import main

    with tempfile.TemporaryDirectory() as tmp:
        link = Path(tmp) / name
        link.symlink_to(dataset, target_is_directory=True)
        code = main(["show", str(link), "--out", str(Path(tmp) / "frame.png")])
        assert code == 0, capsys.readouterr().err
        assert (Path(tmp) / "frame.png").stat().st_size > 1000
