"""The symbolic (CasADi) forward kinematics equal the model's numba kernel."""

import numpy as np
import pytest

from hybridfit import registry
from hybridfit.model.casadi import casadi_forward


@pytest.mark.parametrize("config", [{}, {"mirror": True}, {"scale": 0.9, "bone_lengths": {"index_proximal": 45.0}}])
def test_casadi_forward_matches_model_forward(config):
    ca = pytest.importorskip("casadi")
    model = registry.create("model", "hand26", config)
    x = ca.SX.sym("x", model.n_params)
    fk = ca.Function("fk", [x], [casadi_forward(model.kinematic_tree(), x)])
    rng = np.random.default_rng(0)
    lower, upper = model.bounds()
    lower[:3], upper[:3] = -200.0, 200.0
    X = rng.uniform(lower, upper, (16, model.n_params))
    X[0] = model.default_params()
    X[1, 3:7] = 0.0  # a zero quaternion is the identity, as in the numba kernel
    got = np.stack([np.asarray(fk(row)) for row in X])
    np.testing.assert_allclose(got, model.forward(X), atol=1e-9)


def test_constant_parameters_fold_into_constants():
    ca = pytest.importorskip("casadi")
    model = registry.create("model", "hand26")
    params = [float(v) for v in model.default_params()]
    z = ca.SX.sym("z")
    params[7] = z  # only the thumb's CMC flexion is free
    joints = casadi_forward(model.kinematic_tree(), params)
    fk = ca.Function("fk", [z], [joints])
    np.testing.assert_allclose(np.asarray(fk(params_value := model.default_params()[7])),
                               model.forward(model.default_params()), atol=1e-9)
    assert params_value == model.default_params()[7]
    # the wrist does not depend on the thumb
    assert not ca.depends_on(joints[0, :], z)
