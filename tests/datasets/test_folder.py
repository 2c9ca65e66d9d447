import json
import os

import numpy as np
import pytest

import hybridfit
from hybridfit.datasets.camera import Intrinsics, xyz_to_uvd
from hybridfit.datasets.folder import load_dataset, write_dataset
from hybridfit.errors import HybridfitError
from hybridfit.model.render import Renderer
from hybridfit.synthetic.proposals import random_poses

F = 6


@pytest.fixture(scope="module")
def rendered():
    model = hybridfit.create("model", "hand26")
    params = random_poses(model, F, np.random.default_rng(0))
    depth, parts = Renderer(model).render(params)
    return depth, parts, model.forward(params), params, list(model.joint_names)


def write(path, rendered, **kw):
    depth, parts, joints, params, names = rendered
    return write_dataset(path, depth, parts, joints, params, Intrinsics(), names,
                         {"generator": "test", "config": {"a": 1}, "seed": 7, "extra": [1, 2]}, **kw)


@pytest.mark.parametrize("cache", [True, False])
def test_write_load_round_trip(tmp_path, rendered, cache):
    depth, parts, joints, params, names = rendered
    path = write(tmp_path / "ds", rendered, cache=cache)
    assert (path / "depth.npy").exists() == cache
    ds = load_dataset(path)
    assert len(ds) == ds.frames == F and ds.joint_names == names
    assert ds.intrinsics == Intrinsics()
    np.testing.assert_array_equal(ds.joints_xyz, joints)
    np.testing.assert_allclose(ds.joints_uvd, xyz_to_uvd(joints, Intrinsics()))
    np.testing.assert_array_equal(ds.params, params)
    assert np.array_equal(ds.depth(3), depth[3]) and ds.depth(3).dtype == np.uint16
    assert np.array_equal(ds.parts(-1), parts[-1]) and ds.parts(0).dtype == np.uint8
    assert np.array_equal(ds.depths(), depth) and np.array_equal(ds.part_labels(), parts)
    assert np.array_equal(ds.depths([4, 1]), depth[[4, 1]])
    assert np.array_equal(ds.part_labels(np.array([2])), parts[[2]])
    meta = json.loads((path / "meta.json").read_text())
    assert {k: meta[k] for k in ("format", "version", "generator", "config", "seed", "frames")} == {
        "format": "hybridfit-dataset", "version": 1, "generator": "test", "config": {"a": 1}, "seed": 7, "frames": F}
    assert meta["joint_names"] == names and meta["extra"] == [1, 2] and ds.meta == meta
    assert meta["intrinsics"] == {"fx": 241.42, "fy": 241.42, "cx": 160.0, "cy": 120.0, "width": 320, "height": 240}
    with np.load(path / "labels.npz") as labels:
        assert sorted(labels.files) == ["files", "intrinsics", "joints_uvd", "joints_xyz", "params"]
        assert labels["intrinsics"].shape == (F, 4) and list(labels["files"]) == [f"{i:06d}.png" for i in range(F)]
    assert sorted(os.listdir(path / "depth")) == sorted(os.listdir(path / "parts")) == [f"{i:06d}.png" for i in range(F)]
    with pytest.raises(HybridfitError, match="frame 6 out of range"):
        ds.depth(F)


def test_params_are_optional(tmp_path, rendered):
    depth, parts, joints, _, names = rendered
    ds = load_dataset(write_dataset(tmp_path / "ds", depth, parts, joints, None, Intrinsics(), names, {}))
    assert ds.params.shape == (F, 0) and ds.meta["generator"] == "unknown"


def test_rewrite_replaces_a_data_set_and_refuses_other_folders(tmp_path, rendered):
    path = write(tmp_path / "ds", rendered)
    depth, parts, joints, params, names = rendered
    write_dataset(path, depth[:2], parts[:2], joints[:2], params[:2], Intrinsics(), names, {})
    assert load_dataset(path).frames == 2 and len(os.listdir(path / "depth")) == 2
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("keep me")
    with pytest.raises(HybridfitError, match="not a hybridfit data set; refusing"):
        write(other, rendered)
    assert (other / "notes.txt").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "mine"]


def test_a_failed_write_leaves_nothing_that_looks_complete(tmp_path, rendered, monkeypatch):
    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez", boom)
    with pytest.raises(OSError, match="disk full"):
        write(tmp_path / "ds", rendered)
    assert list(tmp_path.iterdir()) == []
    monkeypatch.undo()
    path = write(tmp_path / "ds", rendered)
    monkeypatch.setattr(np, "savez", boom)
    depth, parts, joints, params, names = rendered
    with pytest.raises(OSError):
        write_dataset(path, depth[:1], parts[:1], joints[:1], params[:1], Intrinsics(), names, {})
    assert load_dataset(path).frames == F  # the old data set is intact
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]


@pytest.mark.parametrize("change, match", [
    (lambda d: d.update(depth=d["depth"].astype(np.int32)), "depth must be"),
    (lambda d: d.update(parts=d["parts"][:, :10]), "parts must be"),
    (lambda d: d.update(joints=d["joints"][:, :5]), "joints_xyz must have shape"),
    (lambda d: d["joints"].__setitem__((1, 2, 0), np.nan), "NaN"),
    (lambda d: d.update(intrinsics=Intrinsics(width=300)), "intrinsics say 300x240"),
    (lambda d: d.update(meta={"seed": object()}), "JSON"),
])
def test_bad_arrays_are_refused(tmp_path, rendered, change, match):
    depth, parts, joints, params, names = rendered
    d = {"depth": depth, "parts": parts, "joints": joints.copy(), "intrinsics": Intrinsics(), "meta": {}}
    change(d)
    with pytest.raises(HybridfitError, match=match):
        write_dataset(tmp_path / "ds", d["depth"], d["parts"], d["joints"], params, d["intrinsics"], names, d["meta"])
    assert not (tmp_path / "ds").exists()


@pytest.fixture
def dataset(tmp_path, rendered):
    return write(tmp_path / "ds", rendered)


def test_missing_files_are_named(dataset):
    (dataset / "parts" / "000004.png").unlink()
    with pytest.raises(HybridfitError, match=r"parts/000004.png: missing"):
        load_dataset(dataset)
    (dataset / "labels.npz").unlink()
    with pytest.raises(HybridfitError, match=r"labels.npz: missing"):
        load_dataset(dataset)
    (dataset / "meta.json").unlink()
    with pytest.raises(HybridfitError, match=r"meta.json: missing"):
        load_dataset(dataset)
    with pytest.raises(HybridfitError, match="no such data set folder"):
        load_dataset(dataset / "nope")


def test_corrupt_files_are_named(dataset):
    png = dataset / "depth" / "000002.png"
    png.write_bytes(png.read_bytes()[:60])
    ds = load_dataset(dataset)
    with pytest.raises(HybridfitError, match=r"depth/000002.png: not a readable PNG"):
        ds.depth(2)
    (dataset / "depth.npy").write_bytes(b"\x93NUMPY garbage")
    with pytest.raises(HybridfitError, match=r"depth.npy: corrupt cache"):
        ds.depths()
    (dataset / "depth.npy").unlink()
    with pytest.raises(HybridfitError, match=r"000002.png"):
        ds.depths()  # decoded from the PNGs now
    (dataset / "labels.npz").write_bytes(b"PK not a zip")
    with pytest.raises(HybridfitError, match=r"labels.npz: not a readable"):
        load_dataset(dataset)
    (dataset / "meta.json").write_text("{ nope")
    with pytest.raises(HybridfitError, match=r"meta.json: not valid JSON"):
        load_dataset(dataset)
    (dataset / "meta.json").write_text(json.dumps({"format": "hybridfit-dataset", "version": 99}))
    with pytest.raises(HybridfitError, match="version 99 is not supported"):
        load_dataset(dataset)


def test_wrong_label_shapes_are_named(dataset, rendered):
    with np.load(dataset / "labels.npz") as z:
        labels = dict(z)
    labels["joints_uvd"] = labels["joints_uvd"][:3]
    np.savez(dataset / "labels.npz", **labels)
    with pytest.raises(HybridfitError, match=r"labels.npz: 'joints_uvd' must have shape \(6, 21, 3\)"):
        load_dataset(dataset)


def test_a_png_of_the_wrong_size_is_named(dataset):
    from PIL import Image

    Image.fromarray(np.zeros((10, 10), np.uint8)).save(dataset / "parts" / "000001.png")
    with pytest.raises(HybridfitError, match=r"parts/000001.png: expected a 320x240 uint8 image"):
        load_dataset(dataset).parts(1)


def test_a_replacement_keeps_other_files_and_an_interrupted_one_can_be_redone(tmp_path, rendered, monkeypatch):
    import hybridfit.datasets.folder as folder

    path = write(tmp_path / "ds", rendered)
    (path / "fits.npz").write_text("the user's")
    depth, parts, joints, params, names = rendered
    real = os.replace

    def fail_on_labels(src, dst):
        if str(dst).endswith("labels.npz"):
            raise OSError(28, "No space left on device")
        return real(src, dst)

    monkeypatch.setattr(folder.os, "replace", fail_on_labels)
    with pytest.raises(HybridfitError, match="cannot write"):
        write_dataset(path, depth[:2], parts[:2], joints[:2], params[:2], Intrinsics(), names, {})
    monkeypatch.undo()
    with pytest.raises(HybridfitError, match="meta.json: missing"):  # never taken for complete
        load_dataset(path)
    write_dataset(path, depth[:2], parts[:2], joints[:2], params[:2], Intrinsics(), names, {})  # still ours
    assert load_dataset(path).frames == 2 and (path / "fits.npz").read_text() == "the user's"
    assert sorted(os.listdir(path)) == ["depth", "depth.npy", "fits.npz", "labels.npz", "meta.json", "parts", "parts.npy"]
    assert sorted(os.listdir(tmp_path)) == ["ds"]
