"""`hybridfit view`: the page it writes draws the hand in a real headless browser (Debian's
chromium; CI installs it in .ci/run). Skipped where /usr/bin/chromium is missing."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from hybridfit.cli import main
from hybridfit.exports.viewer import BONE_COLOURS

from ..exports._fits import make_fits

CHROMIUM = Path("/usr/bin/chromium")
needs_chromium = pytest.mark.skipif(not CHROMIUM.exists(),
                                    reason="no /usr/bin/chromium (apt-get install chromium; .ci/run does)")


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    root = tmp_path_factory.mktemp("view")
    make_fits(root / "fits.npz", frames=3, failed=(1,))
    assert main(["view", str(root / "fits.npz"), "--out", str(root / "hand.html")]) == 0
    return root / "hand.html"


def browse(page: Path, tmp_path: Path, fragment: str = "") -> tuple[str, np.ndarray]:
    """(the DOM after the page's script ran, the screenshot as (H, W, 3) uint8) of an 800 x 600 window."""
    shot = tmp_path / f"shot{len(list(tmp_path.glob('shot*')))}.png"
    done = subprocess.run(
        [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}", "--dump-dom", "--window-size=800,600",
         page.as_uri() + fragment],
        capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and shot.exists(), done.stderr[-2000:]
    with Image.open(shot) as im:
        return done.stdout, np.asarray(im.convert("RGB"))


def bone_pixels(image: np.ndarray) -> int:
    colours = np.array([[int(c[i:i + 2], 16) for i in (1, 3, 5)] for c in BONE_COLOURS])
    near = np.abs(image[:, :, None, :].astype(int) - colours[None, None]).max(axis=-1) <= 12
    return int(near.any(axis=-1).sum())


def test_the_page_is_self_contained(page):
    text = page.read_text()
    assert "<canvas" in text and "<script src" not in text and "<link" not in text
    assert not re.search(r"https?://", text), "the page must load nothing from the network"
    assert '"names":["wrist"' in text


@needs_chromium
def test_a_headless_browser_draws_the_hand(page, tmp_path):
    dom, image = browse(page, tmp_path)
    assert 'data-drawn="20"' in dom and 'data-frame="0"' in dom  # hand26: 20 bones
    assert image.shape == (600, 800, 3)
    assert bone_pixels(image) > 1500, "no bones drawn"
    # another frame, turned: drawn, and not the same picture
    dom, turned = browse(page, tmp_path, "#frame=2&yaw=1.2&pitch=-0.5&names=1")
    assert 'data-drawn="20"' in dom and 'data-frame="2"' in dom
    assert bone_pixels(turned) > 1500 and (turned != image).any(axis=-1).sum() > 2000


@needs_chromium
def test_a_failed_frame_draws_no_hand(page, tmp_path):
    dom, image = browse(page, tmp_path, "#frame=1")
    assert 'data-drawn="0"' in dom and 'data-frame="1"' in dom
    assert bone_pixels(image) < 50


def test_view_refuses_a_fits_file_without_its_model(tmp_path, capsys):
    make_fits(tmp_path / "old.npz", frames=1, named=False)
    assert main(["view", str(tmp_path / "old.npz"), "--out", str(tmp_path / "hand.html")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "older hybridfit" in err and "re-run `hybridfit fit`" in err
    assert not (tmp_path / "hand.html").exists()
