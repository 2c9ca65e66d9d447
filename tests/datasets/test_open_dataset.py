"""Format detection."""

import pytest

from hybridfit import HybridfitError
from hybridfit.datasets import ICVL, MSRA, NYU, detect, open_dataset


def test_detects_each_format(icvl_dir, tmp_path_factory):
    assert detect(icvl_dir) == "icvl" and isinstance(open_dataset(icvl_dir), ICVL)
    assert isinstance(open_dataset(icvl_dir / "labels.txt"), ICVL)


def test_detects_nyu_and_msra(nyu_dir, msra_dir):
    assert isinstance(open_dataset(nyu_dir), NYU)
    assert isinstance(open_dataset(msra_dir), MSRA) and detect(msra_dir / "P0" / "1") == "msra"


def test_synthetic_folder_is_detected(tmp_path):
    (tmp_path / "meta.json").write_text("{}")
    assert detect(tmp_path) == "synthetic"


def test_unknown_folder(tmp_path):
    with pytest.raises(HybridfitError, match="not a recognised data set"):
        open_dataset(tmp_path)
    with pytest.raises(HybridfitError, match="no such file or folder"):
        open_dataset(tmp_path / "missing")
