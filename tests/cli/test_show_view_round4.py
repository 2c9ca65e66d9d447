"""Bad input, round 4 (issue 39), for ``show``, ``view`` and ``evaluate --plot``: file and
folder names drawn as literal text (``$`` is no mathtext, bytes that are not UTF-8 no
crash), frame rates a GIF can hold, and a fits file with nothing to view refused in one line.

Each test failed on the code before the change."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from PIL import Image

from hybridfit.cli import main
from hybridfit.cli.evaluate import plot_success
from hybridfit.cli.show import GIF_FPS
from hybridfit.metrics import SUCCESS_THRESHOLDS_MM

from ..exports._fits import make_fits


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("show4") / "seq"
    assert main(["synth", "test", "--out", str(out), "--frames", "2"]) == 0
    return out


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    root = tmp_path_factory.mktemp("view4")
    arrays = make_fits(root / "fits.npz", frames=2)
    return root / "fits.npz", arrays


def one_line_error(capsys, code: int) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and err.count("\n") == 1 and err.startswith("hybridfit: error: "), err
    return err


# ----------------------------------------------------------------- 3: a GIF's frame rate


@pytest.mark.parametrize("fps", ["0.001", "1000"])
def test_show_refuses_a_frame_rate_a_gif_cannot_hold(dataset, tmp_path, capsys, fps):
    gif = tmp_path / "a.gif"
    err = one_line_error(capsys, main(["show", str(dataset), "--frames", "0:2", "--out", str(gif), "--fps", fps]))
    assert "--fps" in err and fps in err and f"from {GIF_FPS[0]:g} to {GIF_FPS[1]:g}" in err, err
    assert not gif.exists()


def test_show_writes_a_gif_at_the_slowest_frame_rate(dataset, tmp_path):
    gif = tmp_path / "a.gif"
    assert main(["show", str(dataset), "--frames", "0:2", "--out", str(gif), "--fps", f"{GIF_FPS[0]:g}"]) == 0
    with Image.open(gif) as im:
        assert im.n_frames == 2 and im.info["duration"] == 1000 / GIF_FPS[0]


# ----------------------------------------------------------------- 5, 6: names drawn as they are


@pytest.mark.parametrize("name", ["seq_$5_vs_$10", "seq_\udcff"])
def test_show_draws_a_folder_name_with_dollars_or_bytes_that_are_not_utf8(dataset, tmp_path, name):
    link = tmp_path / name
    link.symlink_to(dataset, target_is_directory=True)
    assert main(["show", str(link), "--out", str(tmp_path / "frame.png")]) == 0
    assert main(["show", str(link), "--frames", "0:2", "--out", str(tmp_path / "anim.gif")]) == 0
    assert Image.open(tmp_path / "frame.png").size[0] > 400


def test_evaluate_plots_a_file_name_with_two_dollars(fits, tmp_path):
    _, arrays = fits
    path = tmp_path / "cost_$5_vs_$10.npz"
    np.savez(path, **arrays, ground_truth=arrays["joints"] + 3.0)
    assert main(["evaluate", str(path), "--plot", str(tmp_path / "s.png")]) == 0
    assert Image.open(tmp_path / "s.png").size[0] > 300


@pytest.mark.parametrize("label", ["f\udcff.npz", "$x$ and $", "<b>\x00</b>"])
def test_success_curves_plot_any_label(tmp_path, label):
    curve = np.linspace(0, 1, len(SUCCESS_THRESHOLDS_MM))
    plot_success([(label, curve)], str(tmp_path / "s.png"), f"Success on {label}")
    assert Image.open(tmp_path / "s.png").size[0] > 300


def test_view_of_a_file_whose_name_is_not_utf8(fits, tmp_path):
    path, arrays = fits
    odd = tmp_path / "f\udcff.npz"
    odd.write_bytes(path.read_bytes())
    assert main(["view", str(odd), "--out", str(tmp_path / "hand.html")]) == 0
    text = (tmp_path / "hand.html").read_bytes().decode("utf-8")  # valid UTF-8
    data = json.loads(re.search(r'<script type="application/json" id="hand-data">(.*?)</script>', text).group(1))
    assert data["source"] == "f\udcff.npz" and len(data["joints"]) == 2
    assert "<title>f\\udcff.npz" in text  # the character that stands for the byte, as an escape


# ----------------------------------------------------------------- 9: nothing to view


def test_view_refuses_a_fits_file_without_frames(fits, tmp_path, capsys):
    _, arrays = fits
    empty = {k: (v[:0] if v.ndim and len(v) == 2 else v) for k, v in arrays.items()}
    np.savez(tmp_path / "empty.npz", **empty)
    err = one_line_error(capsys, main(["view", str(tmp_path / "empty.npz"), "--out", str(tmp_path / "hand.html")]))
    assert "empty.npz: no frames" in err and "nothing to view" in err, err
    assert not (tmp_path / "hand.html").exists()


def test_evaluate_refuses_point_names_with_control_characters(fits, tmp_path, capsys):
    _, arrays = fits
    names = arrays["joint_names"].copy()
    names[4] = "tip\x1b[2J"  # a terminal escape: it would clear the screen when the table is printed
    np.savez(tmp_path / "fits.npz", **{**arrays, "joint_names": names, "ground_truth": arrays["joints"]})
    err = one_line_error(capsys, main(["evaluate", str(tmp_path / "fits.npz")]))
    assert "fits.npz: 'joint_names': name 'tip\\x1b[2J' holds control characters" in err, err
