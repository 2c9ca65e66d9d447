import numpy as np

import hybridfit
from hybridfit.datasets.skeletons import dataset_model_config, skeleton
from hybridfit.synthetic.predictors import point_fingers, predictor_errors

GAUSSIAN = {"tail_sd": 0.0, "profile_sd": 0.0}


def _icvl():
    return hybridfit.create("model", "hand26", dataset_model_config("hand26", {}, "icvl")), skeleton("icvl").model_names


def _tail(e):
    """95th percentile over the median of the 3D point errors."""
    n = np.linalg.norm(e, axis=-1)
    return np.percentile(n, 95) / np.median(n)


def test_predictors_have_their_mean_errors_and_err_together():
    model, names = _icvl()
    for design in ({}, GAUSSIAN):
        e = predictor_errors(model, names, 400, np.random.default_rng(0), predictors=3, error_mm=(4.0, 6.0),
                             shared=0.5, **design)
        assert e.shape == (3, 400, 16, 3)
        np.testing.assert_allclose(np.linalg.norm(e, axis=-1).mean((1, 2)), [4.0, 5.0, 6.0])
        a, b = e[0].ravel(), e[1].ravel()
        assert 0.35 < np.corrcoef(a, b)[0, 1] < 0.65  # half the variance shared
        tips = [names.index(f"{f}_tip") for f in ("index", "middle", "ring", "little")]
        assert np.linalg.norm(e[:, :, tips], axis=-1).mean() > np.linalg.norm(e[:, :, 0], axis=-1).mean()
        independent = predictor_errors(model, names, 400, np.random.default_rng(0), shared=0.0, **design)
        assert abs(np.corrcoef(independent[0].ravel(), independent[1].ravel())[0, 1]) < 0.1


def test_the_default_design_is_heavy_tailed_with_its_own_profile_per_predictor():
    model, names = _icvl()
    heavy = predictor_errors(model, names, 2000, np.random.default_rng(0))
    gaussian = predictor_errors(model, names, 2000, np.random.default_rng(0), **GAUSSIAN)
    assert all(_tail(e) > 2.7 for e in heavy) and all(_tail(e) < 2.1 for e in gaussian)
    profile = lambda e: np.log(np.linalg.norm(e[0], axis=-1).mean(0) / np.linalg.norm(e[1], axis=-1).mean(0)).std()  # noqa: E731
    assert profile(heavy) > 0.12 > 0.06 > profile(gaussian)


def test_points_know_their_finger():
    model = hybridfit.create("model", "hand26")
    f = point_fingers(model, ["wrist", "index_mcp", "index_tip", "thumb_tip", "palm_centre"])
    assert f[0] == -1 and f[1] == f[2] and f[2] != f[3]
