import numpy as np
import pytest

from hybridfit.cli import main
from hybridfit.datasets.folder import load_dataset

SMALL_GRID = """
viewpoints_deg = [[0, 0, 0], [0, 0, 30]]
[articulations_deg]
thumb = [[-10, -20, 5, 0], [40, 30, 30, 20]]
index = [[5, 0, 5, 5], [80, 0, 100, 70]]
"""


def test_synth_test_writes_a_data_set(tmp_path, capsys):
    out = tmp_path / "seq"
    assert main(["synth", "test", "--out", str(out), "--frames", "4", "--seed", "3"]) == 0
    ds = load_dataset(out)
    assert ds.frames == 4 and ds.meta["seed"] == 3 and ds.meta["config"]["frames"] == 4
    assert ds.meta["generator"] == "hybridfit.synthetic.sets.make_test"
    assert ds.depths().shape == (4, 240, 320) and (ds.depths() > 0).any()
    assert "wrote the test sequence" in capsys.readouterr().out


def test_synth_train_with_a_settings_file(tmp_path):
    config = tmp_path / "grid.toml"
    config.write_text(SMALL_GRID)
    out = tmp_path / "train"
    assert main(["synth", "train", "--out", str(out), "--config", str(config), "--distance", "450", "--noise"]) == 0
    ds = load_dataset(out)
    assert ds.frames == 2 * 2 * 2
    assert (np.abs(ds.params[:, 2] - 450.0) <= 40.0).all()  # the default distance jitter: +-40 mm
    assert ds.meta["config"]["noise"] is not None and ds.meta["config"]["distance_mm"] == 450


@pytest.mark.parametrize("args, match", [
    (["synth", "test", "--distance", "-5"], "distance_mm"),
    (["synth", "test", "--distance", "45"], "leaves the"),
    (["synth", "train", "--config", "{toml}", "--distance", "60"], "leaves the"),
    (["synth", "test", "--config", "{bad}"], "bad.toml: unknown key 'colour' for synth test"),
    (["synth", "test", "--config", "{far}"], "leaves the 320x240 image"),
    (["synth", "test", "--config", "missing.toml"], "no such file"),
])
def test_bad_input_exits_with_code_2(tmp_path, capsys, args, match):
    (tmp_path / "grid.toml").write_text(SMALL_GRID)
    (tmp_path / "bad.toml").write_text("colour = 'blue'\n")
    (tmp_path / "far.toml").write_text("[intrinsics]\nfx = 2000\nfy = 2000\n")
    args = [a.format(toml=tmp_path / "grid.toml", bad=tmp_path / "bad.toml", far=tmp_path / "far.toml") for a in args]
    assert main(args + ["--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert match in err and err.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_synth_test_over_a_data_set_replaces_only_its_own_files(tmp_path):
    out = tmp_path / "seq"
    assert main(["synth", "test", "--out", str(out), "--frames", "3", "--seed", "1"]) == 0
    users = {"notes.txt": "my notes", "fits/fit.npz": "my fits", "depth/README": "mine too"}
    for name, text in users.items():
        (out / name).parent.mkdir(exist_ok=True)
        (out / name).write_text(text)
    assert main(["synth", "test", "--out", str(out), "--frames", "2", "--seed", "2"]) == 0
    for name, text in users.items():
        assert (out / name).read_text() == text, name
    ds = load_dataset(out)
    assert ds.frames == 2 and ds.meta["seed"] == 2 and len(ds.depths()) == 2
    assert sorted(p.name for p in (out / "depth").iterdir()) == ["000000.png", "000001.png", "README"]
    assert sorted(p.name for p in (out / "parts").iterdir()) == ["000000.png", "000001.png"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]  # no temporary folder left


@pytest.mark.parametrize("meta", [None, '{"project": "my hand captures"}'])
def test_synth_test_refuses_a_folder_that_is_not_a_data_set_before_any_work(tmp_path, capsys, monkeypatch, meta):
    import hybridfit.synthetic.sets as sets

    mine = tmp_path / "captures"
    mine.mkdir()
    (mine / "notes.txt").write_text("my notes")
    if meta is not None:
        (mine / "meta.json").write_text(meta)
    monkeypatch.setattr(sets, "render_poses", lambda *a, **k: pytest.fail("rendered before refusing"))
    assert main(["synth", "test", "--out", str(mine), "--frames", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(mine) in err and "not a hybridfit data set" in err
    assert sorted(p.name for p in mine.iterdir()) == sorted(["notes.txt"] + (["meta.json"] if meta else []))
    assert (mine / "notes.txt").read_text() == "my notes"
