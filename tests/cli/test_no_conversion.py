"""The command line converts nothing and re-orders nothing: no coordinate signs, no
dataset conversions, no re-ordering of points by name (all of it lives in hybridfit.datasets)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import hybridfit.cli

CLI = Path(hybridfit.cli.__file__).parent
FORBIDDEN = [r"y_sign", r"z_sign", r"to_dataset", r"from_camera", r"to_camera", r"\bCameraFrame\b",
             r"\* *np\.array\(\[1(\.0)?, *-1", r"for i, n in enumerate\(", r"\[index\[n\] for n in"]


@pytest.mark.parametrize("pattern", FORBIDDEN)
def test_cli_modules_hold_no_conversion_or_reordering(pattern):
    found = [f"{p.name}:{n}" for p in sorted(CLI.glob("*.py"))
             for n, line in enumerate(p.read_text().splitlines(), 1) if re.search(pattern, line)]
    assert not found, f"{pattern!r} in the CLI: {found}"


def test_the_check_finds_a_sign_flip(tmp_path, monkeypatch):
    (tmp_path / "bad.py").write_text("xyz = xyz * np.array([1.0, ds.y_sign, 1.0])\n")
    import sys

    monkeypatch.setattr(sys.modules[__name__], "CLI", tmp_path)
    with pytest.raises(AssertionError, match="y_sign"):
        test_cli_modules_hold_no_conversion_or_reordering("y_sign")
