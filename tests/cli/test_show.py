import numpy as np
import pytest
from PIL import Image

from hybridfit.cli import main
from hybridfit.datasets.folder import load_dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("show") / "seq"
    assert main(["synth", "test", "--out", str(out), "--frames", "3"]) == 0
    return out


def test_show_draws_a_frame_with_estimate_and_proposals(dataset, tmp_path):
    ds = load_dataset(dataset)
    rng = np.random.default_rng(0)
    fits, props = tmp_path / "fits.npz", tmp_path / "props.npz"
    np.savez(fits, joints=ds.joints_xyz + rng.normal(0, 5, ds.joints_xyz.shape))
    np.savez(props, proposals=ds.joints_xyz[:, :, None] + rng.normal(0, 8, (3, 21, 2, 3)),
             confidences=rng.random((3, 21, 2)))
    png = tmp_path / "frame.png"
    assert main(["show", str(dataset), "--frame", "1", "--out", str(png), "--fits", str(fits),
                 "--proposals", str(props)]) == 0
    with Image.open(png) as im:
        assert im.size[0] > 500 and im.size[1] > 400
    assert main(["show", str(dataset), "--out", str(tmp_path / "plain.png")]) == 0


@pytest.mark.parametrize("args, match", [
    (["--frame", "3"], "frame 3 out of range"),
    (["--fits", "{wrong}"], "'joints' has shape"),
    (["--fits", "{props}"], "missing key 'joints'"),
    (["--proposals", "nope.npz"], "no such file"),
])
def test_show_bad_input_exits_with_code_2(dataset, tmp_path, capsys, args, match):
    np.savez(tmp_path / "wrong.npz", joints=np.zeros((2, 21, 3)))
    np.savez(tmp_path / "props.npz", proposals=np.zeros((3, 21, 1, 3)), confidences=np.ones((3, 21, 1)))
    args = [a.format(wrong=tmp_path / "wrong.npz", props=tmp_path / "props.npz") for a in args]
    assert main(["show", str(dataset), "--out", str(tmp_path / "x.png")] + args) == 2
    assert match in capsys.readouterr().err


def test_show_names_a_missing_data_set(tmp_path, capsys):
    assert main(["show", str(tmp_path / "none"), "--out", str(tmp_path / "x.png")]) == 2
    assert "no such data set folder" in capsys.readouterr().err


def test_show_animates_frames_a_to_b_as_a_gif(dataset, tmp_path, capsys):
    ds = load_dataset(dataset)
    fits = tmp_path / "fits.npz"
    joints = ds.joints_xyz + np.random.default_rng(1).normal(0, 5, ds.joints_xyz.shape)
    joints[1] = np.nan  # a failed fit: that frame shows no estimate
    np.savez(fits, joints=joints)
    gif = tmp_path / "anim.gif"
    assert main(["show", str(dataset), "--frames", "1:3", "--out", str(gif), "--fits", str(fits)]) == 0
    assert "wrote 2 GIF frames (frames 1 to 2)" in capsys.readouterr().out
    with Image.open(gif) as im:
        assert im.format == "GIF" and im.n_frames == 2 and im.size[0] > 400
    assert main(["show", str(dataset), "--frames", ":", "--out", str(gif)]) == 0
    with Image.open(gif) as im:
        assert im.n_frames == 3


@pytest.mark.parametrize("args, match", [
    (["--frames", "1:3", "--out", "{tmp}/x.png"], "an animation is written as a GIF"),
    (["--frames", "1:3", "--frame", "1", "--out", "{tmp}/x.gif"], "not both"),
    (["--frames", "5:9", "--out", "{tmp}/x.gif"], "no frames selected out of 3"),
])
def test_show_frames_refused_in_one_line(dataset, tmp_path, capsys, args, match):
    assert main(["show", str(dataset)] + [a.format(tmp=tmp_path) for a in args]) == 2
    assert match in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_the_legend_shows_the_skeleton_lines(dataset):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hybridfit.cli.show import _Overlays, _parents, figure

    ds = load_dataset(dataset)
    args = type("Args", (), {"proposals": None, "fits": None})()
    fig = figure(ds, 0, _parents(ds, "hand26"), _Overlays(args, ds))
    (handle,) = fig.axes[0].get_legend().legend_handles
    assert handle.get_label() == "ground truth" and handle.get_linestyle() == "-" and handle.get_marker() == "o"
    plt.close(fig)
