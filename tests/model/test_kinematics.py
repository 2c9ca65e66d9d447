"""The vectorised sine/cosine and the blocked forward kinematics."""

from __future__ import annotations

import numba as nb
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from hybridfit.model.kinematics import _NO_REASSOC, COLUMNS, sincos1

from ..conftest import random_params


@nb.njit(fastmath=_NO_REASSOC)
def sincos(x, s, c):
    """Elementwise s = sin(x), c = cos(x) by the kernel's :func:`sincos1` (C-contiguous arrays)."""
    xf, sf, cf = x.reshape(-1), s.reshape(-1), c.reshape(-1)
    for i in range(xf.size):
        sf[i], cf[i] = sincos1(xf[i])


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, st.integers(1, 300), elements=st.floats(-1e4, 1e4)))
def test_sincos_is_within_an_ulp_or_two_of_libm(x):
    s, c = np.empty_like(x), np.empty_like(x)
    sincos(x, s, c)
    np.testing.assert_allclose(s, np.sin(x), rtol=0, atol=3e-16 * max(1.0, np.abs(x).max() / 100))
    np.testing.assert_allclose(c, np.cos(x), rtol=0, atol=3e-16 * max(1.0, np.abs(x).max() / 100))


def test_sincos_of_quadrant_boundaries():
    x = np.array([0.0, -0.0, np.pi / 4, np.pi / 2, np.pi, -np.pi, 1.5 * np.pi, 2 * np.pi, -2.5 * np.pi])
    s, c = np.empty_like(x), np.empty_like(x)
    sincos(x, s, c)
    np.testing.assert_allclose(s, np.sin(x), rtol=0, atol=4e-16)
    np.testing.assert_allclose(c, np.cos(x), rtol=0, atol=4e-16)


def test_blocks_do_not_change_a_hypothesis(hand26):
    """Hypotheses in different blocks, or alone, give the same joints (to rounding)."""
    params = random_params(hand26, 2 * COLUMNS + 7, np.random.default_rng(3))
    together = hand26.forward(params)
    alone = np.stack([hand26.forward(p[None])[0] for p in params])
    np.testing.assert_allclose(together, alone, rtol=0, atol=1e-9)


def test_a_stages_blocks_are_the_models_forward(hand26):
    """A stage's block kinematics (the joints it moves recomputed per hypothesis, the fixed
    ones and a moved joint's frame below its own rotations copied from the frame's base) give
    the joints of ``forward`` with the stage's parameters put into the base, for every
    stage-like set of parameters: one finger, the thumb, the global pose, all of them."""
    from hybridfit.model.kinematics import block_kinematics, block_setup, block_views

    t = hand26.kinematic_tree()
    tree = (np.ascontiguousarray(t.parents, dtype=np.int64), np.ascontiguousarray(t.offsets, dtype=np.float64),
            np.ascontiguousarray(t.rest, dtype=np.float64), np.ascontiguousarray(t.rest_is_identity),
            np.ascontiguousarray(t.axes, dtype=np.int64), np.ascontiguousarray(t.axis_params, dtype=np.int64),
            float(t.mirror))
    J, P = len(t.parents), hand26.n_params
    names = list(hand26.parameter_names)
    identity = np.arange(J + 1, dtype=np.int64)
    rng = np.random.default_rng(5)
    base = random_params(hand26, 9, rng)
    for moved in (["index_mcp_flexion", "index_mcp_abduction", "index_pip_flexion", "index_dip_flexion"],
                  [n for n in names if n.startswith("thumb")], names[:7], names):
        pidx = np.array([names.index(n) for n in moved], dtype=np.int64)
        n = 6
        X = random_params(hand26, 9 * n, rng)[:, pidx].reshape(9, n, len(pidx))
        full = np.repeat(base[:, None], n, axis=1)
        full[:, :, pidx] = X
        expected = hand26.forward(full.reshape(-1, P)).reshape(9, n, J, 3)
        every = np.arange(J, dtype=np.int64)
        ints, floats = block_setup(*tree, identity, every, np.ones(J), base, pidx, every, every, n)
        G = ints[9]
        WpB = block_views(ints, floats)[9]
        for f0 in range(0, 9, G):
            f1 = min(9, f0 + G)
            block_kinematics(*tree, ints, floats, f0, f1, X)
            got = WpB[:, :, :(f1 - f0) * n].reshape(J, 3, f1 - f0, n).transpose(2, 3, 0, 1)
            np.testing.assert_allclose(got, expected[f0:f1], rtol=0, atol=1e-9, err_msg=str(moved))
