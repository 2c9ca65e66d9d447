"""Tiny study files shared by the study tests."""

from __future__ import annotations

import pytest

TINY = """
name = "tiny"
seed = 7
seeds = 2

[data]
kind = "synthetic-proposals"
frames = 4
k = 3

[base]
budget = 400

[sweep.grid]
k = [1, 3]
"optimizer_config.schedule" = ["stepwise", "joint"]

[quick]
seeds = 1
data = { frames = 2 }
"""


@pytest.fixture
def tiny_file(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    return path


def write(tmp_path, text: str, name: str = "study.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path
