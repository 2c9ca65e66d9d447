"""HybridEstimator: a frame's random stream follows its index in the input, whichever frames are empty."""

import numpy as np

from hybridfit.fitting.estimator import EMPTY_FRAME, HybridEstimator
from hybridfit.forest import Proposals


def test_empty_frames_do_not_shift_the_other_frames_seeds(frames):
    names = tuple(str(n) for n in frames["joint_names"])
    p, c = frames["proposals"][:3], frames["confidences"][:3]
    est = HybridEstimator("no-forest-needed.npz", budget=400, seed=3)
    full = est.fit_proposals(Proposals(p, c, np.zeros(3, bool), names))
    c0 = c.copy()
    c0[0] = 0.0  # frame 0 has no foreground: no proposals
    part = est.fit_proposals(Proposals(p, c0, np.array([True, False, False]), names))
    assert part.failed.tolist() == [True, False, False] and part.errors == {0: EMPTY_FRAME}
    np.testing.assert_array_equal(part.params[1:], full.params[1:])
