"""Fuzzing the command line: hypothesis derives bad inputs from valid ones (truncated and
byte-flipped files; wrong keys, dtypes and shapes; NaN, inf and extreme values; malformed
TOML and results lines) and runs them through ``hybridfit.cli.main`` in-process: ``fit``,
``evaluate``, ``export-results``, ``show``, ``proposals from-results``, ``study`` and ``propose``.
It also sets semantic traps in well-formed files (permuted or duplicate point names, metres,
the other hand): a fit that ends with exit 0 and no warning must then be a good fit.

Every run must end with a documented exit code (0, 2 or 3), never an exception; a user error
(2) is one line on stderr; an existing output file is never touched by a failed run, and no
temporary file is left behind. ``pytest --fuzz-examples N`` tries N inputs per test (default
a few, for CI); the module prints what it tried.
"""

from __future__ import annotations

import collections
import hashlib
import io
import re
import shutil
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit.cli import main

from ._icvl_files import write_results

DEFAULT_EXAMPLES = 12
CODES = (0, 2, 3)
SENTINEL = b"an existing output that a failed run must not touch"
TALLY: collections.Counter = collections.Counter()


@pytest.fixture(scope="module")
def examples(request) -> int:
    n = request.config.getoption("--fuzz-examples")
    yield DEFAULT_EXAMPLES if n is None else n
    if TALLY:
        codes = ", ".join(f"exit {c}: {TALLY[c]}" for c in CODES if TALLY[c])
        print(f"\nfuzz: {TALLY['inputs']} generated bad inputs ({codes}); "
              f"{TALLY['tracebacks']} tracebacks, {TALLY['destroyed']} outputs destroyed")
        traps = sorted(k for k in TALLY if isinstance(k, str) and k.startswith("trap "))
        if traps:
            print("semantic traps: " + "; ".join(f"{k[5:]}: {TALLY[k]}" for k in traps))


def fuzz(examples: int):
    """Hypothesis settings for one fuzz test (derandomised at the CI default)."""
    return settings(max_examples=examples, deadline=None, database=None, derandomize=examples == DEFAULT_EXAMPLES,
                    suppress_health_check=list(HealthCheck))


# ------------------------------------------------------------------------ mutations

EXTREMES = [np.nan, np.inf, -np.inf, 1e300, -1e300, 0.0, -1.0, 1e-300, 1e6]


@st.composite
def array_mutation(draw, keys):
    """A function dict -> dict that breaks one array of an npz's contents."""
    key = draw(st.sampled_from(keys))
    op = draw(st.sampled_from(["drop", "rename", "dtype", "shape", "value", "scale", "object", "empty", "extra"]))
    seed = draw(st.integers(0, 2**16))
    extreme = draw(st.sampled_from(EXTREMES))
    target = draw(st.sampled_from(["str", "bool", "int8", "complex", "float16"]))
    factor = draw(st.sampled_from([0.0, 1e-3, 1e3, -1.0, 1e200]))

    def mutate(d: dict) -> dict:
        d = dict(d)
        if key not in d:
            d[key] = np.zeros(3)
        a, rng = np.asarray(d[key]), np.random.default_rng(seed)
        if op == "drop":
            del d[key]
        elif op == "rename":
            d[key + "x"] = d.pop(key)
        elif op == "dtype":
            try:
                d[key] = a.astype({"str": str, "bool": bool, "int8": np.int8, "complex": complex,
                                   "float16": np.float16}[target])
            except (ValueError, TypeError):  # names or objects as numbers: store them as bytes instead
                d[key] = a.astype(bytes)
        elif op == "shape":
            d[key] = [a.ravel(), a[..., :-1] if a.ndim else a, a[None], np.swapaxes(a, 0, -1) if a.ndim else a,
                      a.reshape(-1, *a.shape[2:]) if a.ndim > 1 else a][seed % 5]
        elif op == "value" and a.dtype.kind in "iuf" and a.size:
            a = a.astype(float)
            a.ravel()[rng.integers(0, a.size, 1 + seed % 3)] = extreme
            d[key] = a
        elif op == "scale" and a.dtype.kind in "iuf":
            d[key] = a * factor
        elif op == "object":
            d[key] = np.array([{"x": 1}, None], dtype=object)
        elif op == "empty":
            d[key] = a[:0] if a.ndim else np.zeros(0, a.dtype)
        elif op == "extra":
            d[f"extra{seed}"] = rng.normal(size=(2, 3))
        elif a.dtype.kind in "US" and a.size:  # names: a typo, a duplicate or a number
            names = a.astype(object)
            names.ravel()[seed % a.size] = ["wristt", str(names.ravel()[0]), "7", ""][seed % 4]
            d[key] = names.astype(str)
        return d

    return mutate


@st.composite
def byte_mutation(draw):
    """A function bytes -> bytes: truncate, flip bytes or insert garbage."""
    op = draw(st.sampled_from(["truncate", "flip", "insert"]))
    where = draw(st.floats(0, 1))
    count = draw(st.integers(1, 8))
    seed = draw(st.integers(0, 2**16))

    def mutate(b: bytes) -> bytes:
        rng = np.random.default_rng(seed)
        i = int(where * len(b))
        if op == "truncate":
            return b[:i]
        if op == "insert":
            return b[:i] + rng.integers(0, 256, count, dtype=np.uint8).tobytes() + b[i:]
        a = bytearray(b)
        for j in rng.integers(0, len(a), count):
            a[j] ^= int(rng.integers(1, 256))
        return bytes(a)

    return mutate


@st.composite
def line_mutation(draw):
    """A function text -> text that breaks one line of a results file or a TOML file."""
    op = draw(st.sampled_from(["drop-field", "add-field", "replace-field", "drop-line", "blank", "garbage", "dup"]))
    line = draw(st.integers(0, 50))
    field = draw(st.integers(0, 60))
    token = draw(st.sampled_from(["nan", "inf", "-inf", "1e999", "abc", "0x10", "", "[", "]", "=", '"', "\x00",
                                  "1,5", "true", "{a = 1}", "-1e308", "é"]))

    def mutate(text: str) -> str:
        lines = text.splitlines() or [""]
        n = line % len(lines)
        fields = lines[n].split(" ")
        f = field % len(fields)
        if op == "drop-field":
            del fields[f]
        elif op == "add-field":
            fields.insert(f, token or "1")
        elif op == "replace-field":
            fields[f] = token
        elif op == "drop-line":
            lines.pop(n)
            return "\n".join(lines) + "\n"
        elif op == "blank":
            fields = [""]
        elif op == "garbage":
            fields = [token * 3]
        else:
            lines.insert(n, lines[n])
            return "\n".join(lines) + "\n"
        lines[n] = " ".join(fields)
        return "\n".join(lines) + "\n"

    return mutate


# ------------------------------------------------------------------------ running


def run_cli(argv: list[str], out=None, capsys=None, said: list | None = None) -> int:
    """Run the CLI; check the exit code, the one-line error, the untouched output and that
    no temporary file is left. ``said``: a list that receives the warnings given."""
    if out is not None:
        out.write_bytes(SENTINEL)
    capsys.readouterr()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            code = main(argv)
        except BaseException as err:  # any exception escaping main is a traceback for the user
            TALLY["tracebacks"] += 1
            raise AssertionError(f"{argv}: {type(err).__name__}: {err}") from err
    if said is not None:
        said.extend(str(w.message) for w in caught)
    err = capsys.readouterr().err
    TALLY["inputs"] += 1
    TALLY[code] += 1
    assert code in CODES, f"{argv}: exit code {code}\n{err}"
    assert "Traceback" not in err, err
    if code == 2:
        lines = [ln for ln in err.splitlines() if not ln.startswith("hybridfit: warning:")]
        assert len(lines) == 1 and lines[0].startswith("hybridfit: error: "), err
    if out is not None:
        if code == 2 and out.read_bytes() != SENTINEL:
            TALLY["destroyed"] += 1
            raise AssertionError(f"{argv}: a failed run changed {out}")
        leftovers = [p.name for p in out.parent.iterdir() if p.name.startswith(".hybridfit-") or ".tmp" in p.name]
        assert not leftovers, leftovers
    return code


@pytest.fixture(scope="module")
def valid(tmp_path_factory):
    """Valid inputs: proposals, fits, a results file, a settings file, a study and a forest."""
    root = tmp_path_factory.mktemp("fuzz-valid")
    files = {"proposals": root / "proposals.npz", "fits": root / "fits.npz", "toml": root / "pso.toml",
             "study": root / "study.toml", "data": root / "seq", "forest": root / "forest.npz"}
    np.savez(files["proposals"], **hybridfit.synthetic_proposals(2, seed=1))
    assert main(["fit", str(files["proposals"]), "--out", str(files["fits"]), "--budget", "100",
                 "--optimizer", "pso"]) == 0
    files["results"], _ = write_results(root, frames=2, name="results.txt")
    files["toml"].write_text('particles = 10\ninertia = 0.7\n')
    files["study"].write_text('name = "fuzz"\nseeds = 1\n\n[data]\nkind = "synthetic-proposals"\nframes = 2\nk = 2\n\n'
                              '[base]\nbudget = 200\n\n[sweep.grid]\nk = [1, 2]\n\n[quick]\ndata = { frames = 1 }\n')
    assert main(["synth", "test", "--out", str(files["data"]), "--frames", "2"]) == 0
    assert main(["train", str(files["data"]), "--out", str(files["forest"]), "--trees", "1", "--max-depth", "4",
                 "--pixels-per-frame", "50", "--jobs", "1"]) == 0
    return files


def npz_bytes(d: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **d)
    return buf.getvalue()


def load(path) -> dict:
    with np.load(path, allow_pickle=True) as z:
        return dict(z)


def test_fit_on_generated_bad_proposals(valid, tmp_path_factory, capsys, examples):
    good = load(valid["proposals"])
    keys = sorted(good)

    @fuzz(examples)
    @given(st.lists(array_mutation(keys), min_size=1, max_size=3), st.one_of(st.none(), byte_mutation()))
    def check(mutations, flip):
        d = good
        for m in mutations:
            d = m(d)
        raw = npz_bytes(d)
        work = tmp_path_factory.mktemp("fit")
        src, out = work / "p.npz", work / "fits.npz"
        src.write_bytes(flip(raw) if flip else raw)
        run_cli(["fit", str(src), "--out", str(out), "--budget", "100", "--optimizer", "pso"], out, capsys)

    check()


def test_evaluate_export_and_show_on_generated_bad_fits(valid, tmp_path_factory, capsys, examples):
    good = load(valid["fits"])

    @fuzz(examples)
    @given(st.lists(array_mutation(sorted(good)), min_size=1, max_size=3), st.one_of(st.none(), byte_mutation()),
           st.sampled_from(["evaluate", "export-results", "show"]))
    def check(mutations, flip, command):
        d = good
        for m in mutations:
            d = m(d)
        work = tmp_path_factory.mktemp("eval")
        src = work / "fits.npz"
        raw = npz_bytes(d)
        src.write_bytes(flip(raw) if flip else raw)
        if command == "evaluate":
            out = work / "curve.png"
            run_cli(["evaluate", str(src), "--plot", str(out)], out, capsys)
        elif command == "export-results":  # hand26 points are not ICVL's: most runs end in exit 2 by design
            out = work / "fitted.txt"
            run_cli(["export-results", str(src), "--dataset", "msra", "--out", str(out)], out, capsys)
        else:
            out = work / "frame.png"
            run_cli(["show", str(valid["data"]), "--frame", "1", "--fits", str(src), "--out", str(out)], out, capsys)

    check()


def test_results_files_with_generated_bad_lines(valid, tmp_path_factory, capsys, examples):
    text = valid["results"].read_text()

    @fuzz(examples)
    @given(st.lists(line_mutation(), min_size=1, max_size=3), st.one_of(st.none(), byte_mutation()),
           st.booleans())
    def check(mutations, flip, as_truth):
        t = text
        for m in mutations:
            t = m(t)
        work = tmp_path_factory.mktemp("results")
        src, out = work / "bad.txt", work / "p.npz"
        raw = t.encode("utf-8", "surrogateescape")
        src.write_bytes(flip(raw) if flip else raw)
        if as_truth:
            run_cli(["evaluate", str(valid["results"]), "--dataset", "icvl", "--ground-truth", str(src)], None, capsys)
        else:
            run_cli(["proposals", "from-results", "--dataset", "icvl", str(src), "--out", str(out)], out, capsys)

    check()


def test_settings_and_study_files_with_generated_bad_toml(valid, tmp_path_factory, capsys, examples):
    @fuzz(examples)
    @given(st.sampled_from(["toml", "study"]), st.lists(line_mutation(), min_size=1, max_size=3),
           st.one_of(st.none(), byte_mutation()), st.booleans())
    def check(which, mutations, flip, quick):
        t = valid[which].read_text()
        for m in mutations:
            t = m(t)
        work = tmp_path_factory.mktemp("toml")
        src = work / f"bad.toml"
        raw = t.encode("utf-8", "surrogateescape")
        src.write_bytes(flip(raw) if flip else raw)
        if which == "toml":
            out = work / "fits.npz"
            run_cli(["fit", str(valid["proposals"]), "--out", str(out), "--budget", "100", "--optimizer", "pso",
                     "--optimizer-config", str(src)], out, capsys)
        else:  # validation only: --report-only refuses to run without a database
            code = run_cli(["study", str(src), "--out", str(work / "run"), "--report-only", *(["--quick"] * quick)],
                           None, capsys)
            assert code == 2

    check()


def test_propose_with_generated_bad_forests(valid, tmp_path_factory, capsys, examples):
    good = load(valid["forest"])

    @fuzz(examples)
    @given(st.lists(array_mutation(sorted(good)), min_size=1, max_size=2), st.one_of(st.none(), byte_mutation()))
    def check(mutations, flip):
        d = good
        for m in mutations:
            d = m(d)
        work = tmp_path_factory.mktemp("forest")
        src, out = work / "forest.npz", work / "p.npz"
        raw = npz_bytes(d)
        src.write_bytes(flip(raw) if flip else raw)
        run_cli(["propose", str(src), str(valid["data"]), "--out", str(out), "--frames", "1"], out, capsys)

    check()


TRAPS = ("permuted-names", "duplicate-name", "metres", "proposals-in-metres", "left-hand", "none")
#: a fit without error or warning is at most this far from the ground truth (mean, mm)
SILENT_ERROR_MM = 25.0


def set_trap(trap: str, seed: int) -> dict:
    """Synthetic frames (6, ground truth included) with one semantic trap that numpy reads as valid."""
    rng = np.random.default_rng(seed)
    d = hybridfit.synthetic_proposals(6, seed=seed, model_config={"mirror": trap == "left-hand"})
    names = [str(n) for n in d["joint_names"]]
    if trap == "permuted-names":  # at least half of the points carry another point's name
        idx = rng.permutation(len(names))[: len(names) // 2 + int(rng.integers(1, len(names) // 2))]
        d["joint_names"] = np.asarray(names)
        d["joint_names"][idx] = np.asarray(names)[np.roll(idx, 1)]
    elif trap == "duplicate-name":
        i, j = rng.choice(len(names), 2, replace=False)
        d["joint_names"] = np.asarray([names[j] if k == i else n for k, n in enumerate(names)])
    elif trap in ("metres", "proposals-in-metres"):
        d["proposals"] = d["proposals"] / 1000.0
        if trap == "metres":
            d["ground_truth"] = d["ground_truth"] / 1000.0
    return d


def test_fit_on_semantic_traps(tmp_path_factory, capsys, examples):
    @fuzz(examples)
    @given(st.sampled_from(TRAPS), st.integers(0, 2**16))
    def check(trap, seed):
        d = set_trap(trap, seed)
        work = tmp_path_factory.mktemp("trap")
        src, out = work / "p.npz", work / "fits.npz"
        np.savez(src, **d)
        said: list[str] = []
        code = run_cli(["fit", str(src), "--out", str(out), "--budget", "300", "--seed", str(seed % 7)], out, capsys,
                       said)
        TALLY[f"trap {trap}: exit {code}{' + warning' if said else ''}"] += 1
        if code == 0 and not said:  # no word said: the fit must be good
            with np.load(out) as fits:
                error = float(np.mean(np.linalg.norm(fits["joints"] - d["ground_truth"], axis=-1)))
            assert error < SILENT_ERROR_MM, f"trap {trap} (seed {seed}): silent {error:.1f} mm fit"

    check()


#: the numeric classes of bad values (issue 33): each must be refused in one line naming the
#: key, or (confidences near the largest float, whose sum overflows) fitted as their normalised
#: values, never fitted silently as something else
NUMERIC_CLASSES = ("nan", "inf", "-inf", "huge", "-huge", "complex", "overflowing-confidences")


def numeric_class(d: dict, key: str, kind: str, seed: int) -> dict:
    """Frames ``d`` with one numeric class of bad values put into ``key``, at random places."""
    rng = np.random.default_rng(seed)
    d = dict(d)
    if kind == "overflowing-confidences":
        c = d["confidences"]
        d["confidences"] = c / c.max() * rng.uniform(1e307, np.finfo(float).max)
        return d
    a = np.asarray(d[key], dtype=complex if kind == "complex" else float).copy()
    at = rng.integers(0, a.size, 1 + seed % 3)
    value = {"nan": np.nan, "inf": np.inf, "-inf": -np.inf, "huge": rng.choice([1e300, 1e30, 1e7, 3e6]),
             "-huge": -rng.choice([1e300, 1e9, 2e6])}.get(kind)
    if kind == "complex":
        a.ravel()[at] += 1j * rng.uniform(0.1, 10)
    else:
        a.ravel()[at] = value
    d[key] = a
    return d


def test_fit_refuses_generated_numeric_classes(valid, tmp_path_factory, capsys, examples):
    good = load(valid["proposals"])

    @fuzz(examples)
    @given(st.sampled_from(NUMERIC_CLASSES), st.sampled_from(["proposals", "confidences", "ground_truth"]),
           st.integers(0, 2**16))
    def check(kind, key, seed):
        if kind in ("huge", "-huge") and key == "confidences":  # any positive scale is a valid confidence
            key = "proposals"
        d = numeric_class(good, key, kind, seed)
        work = tmp_path_factory.mktemp("numeric")
        src, out = work / "p.npz", work / "fits.npz"
        np.savez(src, **d)
        code = run_cli(["fit", str(src), "--out", str(out), "--budget", "100", "--optimizer", "pso"], out, capsys)
        TALLY[f"trap numeric {kind}: exit {code}"] += 1
        if kind == "overflowing-confidences":  # fitted as the same confidences, normalised
            assert code == 0
            plain = work / "plain.npz"
            np.savez(src, **{**d, "confidences": good["confidences"]})
            assert run_cli(["fit", str(src), "--out", str(plain), "--budget", "100", "--optimizer", "pso"], None,
                           capsys) == 0
            with np.load(out) as a, np.load(plain) as b:
                assert np.allclose(a["joints"], b["joints"])
            return
        assert code == 2, f"{kind} in {key!r} was not refused"  # (run_cli checked the one line)

    check()


def test_evaluate_refuses_generated_non_finite_objectives(valid, tmp_path_factory, capsys, examples):
    good = load(valid["fits"])

    @fuzz(examples)
    @given(st.sampled_from(["nan", "inf", "-inf"]), st.integers(0, 2**16), st.booleans())
    def check(kind, seed, marked_failed):
        d = dict(good)
        f = seed % len(d["objective"])
        d["objective"] = d["objective"].copy()
        d["objective"][f] = {"nan": np.nan, "inf": np.inf, "-inf": -np.inf}[kind]
        if marked_failed:  # a failed frame's NaN is a failure, as documented
            d["failed"] = d["failed"].copy()
            d["failed"][f] = True
            d["joints"] = d["joints"].copy()
            d["joints"][f] = np.nan
        work = tmp_path_factory.mktemp("objective")
        src = work / "fits.npz"
        np.savez(src, **d)
        code = run_cli(["evaluate", str(src)], None, capsys)
        assert code == (0 if marked_failed else 2), (kind, marked_failed)

    check()
