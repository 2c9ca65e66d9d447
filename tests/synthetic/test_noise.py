import numpy as np
import pytest

import hybridfit
from hybridfit.datasets.camera import Intrinsics
from hybridfit.synthetic.noise import SensorNoise, apply_noise
from hybridfit.model.render import Renderer
from hybridfit.synthetic.proposals import random_poses


@pytest.fixture(scope="module")
def clean():
    model = hybridfit.create("model", "hand26")
    return Renderer(model).render(random_poses(model, 4, np.random.default_rng(0)))


def test_noise_grows_with_depth_and_drops_pixels(clean):
    depth, parts = clean
    noisy, noisy_parts = apply_noise(depth, parts, Intrinsics(), SensorNoise(), seed=1)
    both = (noisy > 0) & (depth > 0)
    assert ((noisy > 0) <= (depth > 0)).all()  # only removes pixels
    assert 0.6 < both.sum() / (depth > 0).sum() < 0.99
    assert ((noisy == 0) == (noisy_parts == 0)).all()
    assert (noisy_parts[both] == parts[both]).all()
    err = noisy[both].astype(float) - depth[both]
    assert abs(err.mean()) < 0.2 and 0.8 < err.std() < 2.5  # sigma = 1 + 2 (z/m)^2 mm ~ 1.3 mm
    far = SensorNoise(sigma_mm=0, sigma_per_m2=20, holes=0, dropout=0, edge_dropout=0, grazing_deg=90)
    n2, _ = apply_noise(depth, parts, Intrinsics(), far)
    assert (n2 > 0).sum() == (depth > 0).sum()
    assert 2.0 < (n2[depth > 0].astype(float) - depth[depth > 0]).std() < 5.0


def test_noise_is_reproducible_and_independent_of_batching(clean):
    depth, parts = clean
    k, noise = Intrinsics(), SensorNoise()
    a = apply_noise(depth, parts, k, noise, seed=5)
    b = apply_noise(depth[2:], parts[2:], k, noise, seed=5, first_frame=2)
    assert np.array_equal(a[0][2:], b[0]) and np.array_equal(a[1][2:], b[1])
    c = apply_noise(depth, parts, k, noise, seed=6)
    assert not np.array_equal(a[0], c[0])
    assert not np.shares_memory(a[0], depth)


def test_bad_noise_settings_are_refused():
    with pytest.raises(ValueError):
        SensorNoise(sigma_mm=-1)
    with pytest.raises(ValueError, match="hole_radius_px"):
        SensorNoise(hole_radius_px=(3, 1))
