"""`hybridfit view`: the page it writes draws the hand in a real headless browser (Debian's
chromium; CI installs it in .ci/run). Skipped where /usr/bin/chromium is missing. The
shaded surface, hovering and the names are tested in tests/exports/test_viewer_shaded.py."""

from __future__ import annotations

import re

import pytest

from hybridfit.cli import main
from hybridfit.exports.viewer import three_sources

from ..exports._browser import Browser, background, needs_chromium
from ..exports._fits import make_fits

#: surface primitives of hand26: 15 phalanges, 6 palm strands, the thenar and the web
HAND26_PRIMITIVES = 23


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    root = tmp_path_factory.mktemp("view")
    make_fits(root / "fits.npz", frames=3, failed=(1,))
    assert main(["view", str(root / "fits.npz"), "--out", str(root / "hand.html")]) == 0
    return root / "hand.html"


def test_the_page_is_self_contained(page):
    text = page.read_text(encoding="utf-8")
    # three.js is in the page, unchanged; the page's own parts load nothing either
    for name, source in zip(("three-core", "three-module"), three_sources(), strict=True):
        block = f'<script type="text/plain" id="{name}">{source}</script>'
        assert text.count(block) == 1
        text = text.replace(block, "")
    assert "<canvas" in text and "<script src" not in text and "<link" not in text
    assert not re.search(r"https?://", text), "the page must load nothing from the network"
    assert '"names":["wrist"' in text


def hand_fraction(browser: Browser) -> float:
    """The share of the 3D view (below the header) that is not background."""
    top = round(browser.evaluate("document.getElementById('stage').getBoundingClientRect().top"))
    return float((~background(browser.screenshot()[top:-30, 90:])).mean())  # without the axes and help line


@needs_chromium
def test_a_headless_browser_draws_the_hand(page, tmp_path):
    with Browser(tmp_path / "profile") as browser:
        browser.open(page.as_uri())
        assert browser.evaluate("[document.body.dataset.drawn, document.body.dataset.frame]") == [
            str(HAND26_PRIMITIVES), "0"]
        image = browser.screenshot()
        assert image.shape == (600, 800, 3)
        assert hand_fraction(browser) > 0.15, "no hand drawn"
        # another frame, turned: drawn, and not the same picture
        browser.open(page.as_uri() + "#frame=2&yaw=1.2&pitch=-0.5&names=1")
        assert browser.evaluate("[document.body.dataset.drawn, document.body.dataset.frame]") == [
            str(HAND26_PRIMITIVES), "2"]
        turned = browser.screenshot()
        assert hand_fraction(browser) > 0.1 and (turned != image).any(axis=-1).sum() > 2000
        assert browser.console_errors() == []


@needs_chromium
def test_a_failed_frame_draws_no_hand(page, tmp_path):
    with Browser(tmp_path / "profile") as browser:
        browser.open(page.as_uri() + "#frame=1")
        assert browser.evaluate("[document.body.dataset.drawn, document.body.dataset.frame]") == ["0", "1"]
        assert hand_fraction(browser) < 0.01
        assert browser.evaluate("document.getElementById('message').textContent") == "frame 1 could not be fitted"


def test_view_refuses_a_fits_file_without_its_model(tmp_path, capsys):
    make_fits(tmp_path / "old.npz", frames=1, named=False)
    assert main(["view", str(tmp_path / "old.npz"), "--out", str(tmp_path / "hand.html")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "older hybridfit" in err and "re-run `hybridfit fit`" in err
    assert not (tmp_path / "hand.html").exists()
