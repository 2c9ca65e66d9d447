"""`hybridfit export-angles` on generated bad fits files (the fuzzer of test_fuzz.py): every
run ends in exit 0 or one line and exit 2, and a failed run leaves an existing output as it was."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

import hybridfit
from hybridfit.cli import main

from .test_fuzz import array_mutation, byte_mutation, examples, fuzz, npz_bytes, run_cli  # noqa: F401 (fixture)


def test_export_angles_on_generated_bad_fits(tmp_path_factory, capsys, examples):  # noqa: F811
    root = tmp_path_factory.mktemp("angles-valid")
    np.savez(root / "proposals.npz", **hybridfit.synthetic_proposals(2, seed=1))
    assert main(["fit", str(root / "proposals.npz"), "--out", str(root / "fits.npz"), "--budget", "100",
                 "--optimizer", "pso"]) == 0
    with np.load(root / "fits.npz") as f:
        good = {k: f[k] for k in f.files}

    @fuzz(examples)
    @given(st.lists(array_mutation(sorted(good)), min_size=1, max_size=3), st.one_of(st.none(), byte_mutation()),
           st.sampled_from([[], ["--model", "hand26"], ["--model", "hand27"]]))
    def check(mutations, flip, model):
        d = good
        for m in mutations:
            d = m(d)
        work = tmp_path_factory.mktemp("angles")
        src, out = work / "fits.npz", work / "angles.csv"
        raw = npz_bytes(d)
        src.write_bytes(flip(raw) if flip else raw)
        run_cli(["export-angles", str(src), "--out", str(out), *model], out, capsys)

    check()
