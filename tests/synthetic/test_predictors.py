import numpy as np

import hybridfit
from hybridfit.datasets.skeletons import dataset_model_config, skeleton
from hybridfit.synthetic.predictors import point_fingers, predictor_errors


def test_predictors_have_their_mean_errors_and_err_together():
    model = hybridfit.create("model", "hand26", dataset_model_config("hand26", {}, "icvl"))
    names = skeleton("icvl").model_names
    e = predictor_errors(model, names, 400, np.random.default_rng(0), predictors=3, error_mm=(4.0, 6.0), shared=0.5)
    assert e.shape == (3, 400, 16, 3)
    np.testing.assert_allclose(np.linalg.norm(e, axis=-1).mean((1, 2)), [4.0, 5.0, 6.0])
    a, b = e[0].ravel(), e[1].ravel()
    assert 0.35 < np.corrcoef(a, b)[0, 1] < 0.65  # half the variance shared
    tips = [names.index(f"{f}_tip") for f in ("index", "middle", "ring", "little")]
    assert np.linalg.norm(e[:, :, tips], axis=-1).mean() > np.linalg.norm(e[:, :, 0], axis=-1).mean()
    independent = predictor_errors(model, names, 400, np.random.default_rng(0), shared=0.0)
    assert abs(np.corrcoef(independent[0].ravel(), independent[1].ravel())[0, 1]) < 0.1


def test_points_know_their_finger():
    model = hybridfit.create("model", "hand26")
    f = point_fingers(model, ["wrist", "index_mcp", "index_tip", "thumb_tip", "palm_centre"])
    assert f[0] == -1 and f[1] == f[2] and f[2] != f[3]
