"""The page of ``hybridfit view`` draws the model's own surface, shaded (three.js, vendored):
its data are the model's primitives; in a headless browser it loads nothing and logs no
error, the hand fills the view with many shades, the slider changes the pose, hovering
names one joint, the names do not overlap, and a failed frame is marked."""

from __future__ import annotations

import dataclasses
import fnmatch
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from hybridfit.exports.fitted import load_fitted
from hybridfit.exports.viewer import THREE_FILES, page_data, three_sources, write_view
from hybridfit.model.render import HandSurface, Renderer, build_primitives

from ._browser import Browser, background, needs_chromium
from ._fits import make_fits

ROOT = Path(__file__).resolve().parents[2]
THREE = ROOT / "hybridfit" / "exports" / "three"


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    root = tmp_path_factory.mktemp("shaded")
    make_fits(root / "fits.npz", frames=3, failed=(1,))
    return load_fitted(root / "fits.npz")


@pytest.fixture(scope="module")
def page(fits, tmp_path_factory):
    out = tmp_path_factory.mktemp("page") / "hand.html"
    write_view(out, fits)
    return out.as_uri()


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    with Browser(tmp_path_factory.mktemp("profile")) as b:
        yield b


@pytest.mark.parametrize("settings", [{}, {"mirror": True}], ids=["right", "left"])
def test_the_page_draws_the_models_own_surface(tmp_path, settings):
    make_fits(tmp_path / "fits.npz", settings=settings, frames=2)
    fitted = load_fitted(tmp_path / "fits.npz")
    surface = page_data(fitted)["surface"]
    Wa, Wb, ra, rb = build_primitives(fitted.model, HandSurface())
    assert np.allclose(surface["a"], Wa, atol=1e-6) and np.allclose(surface["b"], Wb, atol=1e-6)
    assert np.allclose(surface["ra"], ra, atol=0.01) and np.allclose(surface["rb"], rb, atol=0.01)
    # the end points the page computes (weights @ joints) are the renderer's
    A, B = Renderer(fitted.model).surface_points(fitted.result.model_joints)
    joints = np.array(page_data(fitted)["joints"])
    assert np.allclose(np.einsum("mj,njc->nmc", surface["a"], joints), A, atol=0.01)
    assert np.allclose(np.einsum("mj,njc->nmc", surface["b"], joints), B, atol=0.01)


def test_three_js_is_vendored_whole_and_packaged():
    for name, text in zip(THREE_FILES, three_sources(), strict=True):
        assert text == (THREE / name).read_text(encoding="utf-8")
        assert text.startswith("/**\n * @license\n * Copyright 2010-2026 Three.js Authors\n"
                               " * SPDX-License-Identifier: MIT")
        assert not re.search(r"</script|<!--", text, re.I), f"{name} cannot be written into a <script> as it is"
    assert 'const t="185"' in three_sources()[0]  # REVISION: 0.185.1, as the viewer's docstring says
    assert "MIT License" in (THREE / "LICENSE").read_text(encoding="utf-8")
    patterns = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    for name in (*THREE_FILES, "LICENSE"):  # in the wheel
        assert any(fnmatch.fnmatch(f"three/{name}", p) for p in patterns.get("hybridfit.exports", [])), name


def view_pixels(browser: Browser, image: np.ndarray) -> np.ndarray:
    """(H, W) bool: the pixels of the 3D view that are not background, leaving out the axes and the help line."""
    rects = browser.evaluate("['stage', 'axes', 'help'].map(id => { const r = document.getElementById(id)"
                             ".getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom].map(Math.round); })")
    mask = np.zeros(image.shape[:2], bool)
    x0, y0, x1, y1 = rects[0]
    mask[y0:y1, x0:x1] = True
    for x0, y0, x1, y1 in rects[1:]:
        mask[y0:y1, x0:x1] = False
    return mask & ~background(image)


def fraction(browser: Browser, hand: np.ndarray) -> float:
    w, h = browser.evaluate("(s => [s.clientWidth, s.clientHeight])(document.getElementById('stage'))")
    return hand.sum() / (w * h)


@needs_chromium
def test_the_page_loads_nothing_and_logs_no_error(browser, page):
    browser.events.clear()
    browser.open(page + "#names=1")
    browser.mouse(*browser.evaluate("hybridfitView.screen(8)"))
    assert browser.console_errors() == []
    urls = browser.requests()
    assert urls[0] == page and all(u.startswith("blob:") for u in urls[1:]), urls  # three.js from the page itself
    assert browser.evaluate("document.body.dataset.error") is None


@needs_chromium
def test_a_shaded_hand_fills_the_view(browser, page, tmp_path):
    browser.open(page)
    image = browser.screenshot(Path("/tmp/hybridfit-view-shaded.png"))
    hand = view_pixels(browser, image)
    assert fraction(browser, hand) > 0.15, "the hand must cover the view"
    # shading: inside the hand (3 pixels from its edge), many grey levels over a wide range
    inner = hand.copy()
    for axis in (0, 1):
        for shift in (-3, 3):
            inner &= np.roll(hand, shift, axis=axis)
    grey = image[inner].astype(float) @ [0.299, 0.587, 0.114]
    assert len(np.unique(grey.round())) > 60 and np.percentile(grey, 95) - np.percentile(grey, 5) > 30
    assert browser.evaluate("document.body.dataset.drawn") == str(len(page_data_of(browser)["surface"]["ra"]))


def page_data_of(browser: Browser) -> dict:
    return browser.evaluate("JSON.parse(document.getElementById('hand-data').textContent)")


@needs_chromium
def test_the_slider_moves_through_the_frames_and_marks_the_failed_one(browser, page):
    browser.open(page)
    first = browser.screenshot()
    browser.evaluate("document.getElementById('slider').focus()")
    browser.key("ArrowRight", 39)  # frame 1 failed: no hand, said so, marked under the slider
    assert browser.evaluate("[document.body.dataset.frame, document.body.dataset.drawn]") == ["1", "0"]
    assert "could not be fitted" in browser.evaluate("document.getElementById('message').textContent")
    assert browser.evaluate("document.getElementById('status').textContent").endswith("not fitted")
    assert fraction(browser, view_pixels(browser, browser.screenshot())) < 0.01
    marks = browser.evaluate("[...document.querySelectorAll('#marks span')].map(s => s.style.left)")
    assert marks == ["50%"]  # frame 1 of 0..2
    browser.key("ArrowRight", 39)
    assert browser.evaluate("[document.body.dataset.frame, document.body.dataset.drawn]") == ["2", "23"]  # hand26
    second = browser.screenshot()
    assert (first != second).any(axis=-1).sum() > 5000, "another pose"


@needs_chromium
def test_play_moves_the_frames(browser, page):
    browser.open(page)
    browser.evaluate("document.getElementById('play').click()")
    browser.wait_for("document.body.dataset.frame !== '0'", timeout=5)
    browser.evaluate("document.getElementById('play').click()")


def shown_labels(browser: Browser) -> list[tuple[str, list[float]]]:
    """(text, [left, top, right, bottom]) of every joint name or tooltip on show."""
    return browser.evaluate(
        "[...document.querySelectorAll('#names span, #tip')].filter(e => getComputedStyle(e).display !== 'none')"
        ".map(e => { const r = e.getBoundingClientRect();"
        "            return [e.textContent, [r.left, r.top, r.right, r.bottom]]; })")


@needs_chromium
def test_hovering_names_the_joint_under_the_pointer_and_only_it(browser, page):
    browser.open(page)
    names = page_data_of(browser)["names"]
    assert shown_labels(browser) == []
    tips = [j for j, n in enumerate(names) if n.endswith("_tip")]
    assert len(tips) == 5
    for j in tips:
        browser.mouse(*browser.evaluate(f"hybridfitView.screen({j})"))
        (text, _), = shown_labels(browser)
        assert text.startswith(names[j] + "  (")
    browser.mouse(5, 300)  # off the hand
    assert shown_labels(browser) == []


@needs_chromium
def test_the_names_do_not_overlap(browser, page, tmp_path):
    browser.open(page + "#names=1&yaw=1.2&pitch=-0.5")
    labels = shown_labels(browser)
    J = len(page_data_of(browser)["names"])
    assert J // 2 < len(labels) <= J and browser.evaluate("document.body.dataset.labels") == str(len(labels))
    for i, (_, a) in enumerate(labels):
        for _, b in labels[:i]:
            assert not (a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]), (labels[i], b)


@needs_chromium
def test_markup_in_names_stays_text_in_the_browser(browser, fits, tmp_path):
    from .test_hostile_names import hostile_model

    names = list(fits.model.joint_names)
    names[8] = '<img src="x.png" onerror="document.title=1">'  # the index tip
    names[0] = "</script><b>wrist</b>"
    out = tmp_path / "<b>fits</b>.html"
    write_view(out, dataclasses.replace(fits, model=hostile_model(names)))
    browser.events.clear()
    browser.open(out.as_uri() + "#names=1")
    assert browser.evaluate("document.querySelectorAll('img, b, #names *:not(span)').length") == 0
    assert browser.evaluate("[...document.querySelectorAll('#names span')].map(s => s.textContent)") == names
    browser.mouse(*browser.evaluate("hybridfitView.screen(8)"))
    assert browser.evaluate("document.getElementById('tip').textContent").startswith(names[8] + "  (")
    assert all(u.startswith("blob:") for u in browser.requests()[1:]) and browser.console_errors() == []
