"""A study's time per frame excludes compilation: the trial's warm-up fit leaves nothing for
numba to compile (or load from its cache) in the timed fit (issue 32: a first seed with the
compile in it put the time error bars below 0 ms)."""

from __future__ import annotations

import subprocess
import sys

CODE = """
import numpy as np
from numba.core import dispatcher

import hybridfit
from hybridfit.study import runner

compiled = []
compile_for_args = dispatcher._DispatcherBase._compile_for_args


def spy(self, *args, **kwargs):
    compiled.append(self.py_func.__name__)
    return compile_for_args(self, *args, **kwargs)


dispatcher._DispatcherBase._compile_for_args = spy
calls, local = [], []
real_fit = runner.fit


def fit(proposals, *args, **kwargs):
    before = len(compiled)
    result = real_fit(proposals, *args, **kwargs)
    calls.append((len(proposals), compiled[before:]))
    local.append("levenberg-marquardt" in result.schedule)
    return result


runner.fit = fit
data = {**hybridfit.synthetic_proposals(12, k=3, seed=1), "empty": np.zeros(12, bool)}
# the paper's schedule (no local stage), then the default one (its local stage's kernels are new)
for objective, optimizer_config in (("clamped-confidence", {"local_share": 0.0}), ("clamped-then-soft-l1", {})):
    settings = {"model": "hand26", "objective": objective, "objective_config": {}, "optimizer": "stepwise-pso",
                "optimizer_config": optimizer_config, "budget": 600, "search_radius_mm": 60.0}
    for seed in (1, 2):
        runner.run_trial(settings, {}, seed, data)
print(calls)
assert local == [False] * 3 + [True] * 3, local
warm_up, *timed = calls[:3]
assert warm_up[0] == runner.WARM_UP_FRAMES and warm_up[1], warm_up  # compiles (or loads) the kernels
assert [n for n, _ in timed] == [12, 12] and all(not c for _, c in timed), timed
assert [n for n, _ in calls[3:]] == [runner.WARM_UP_FRAMES, 12, 12] and all(not c for _, c in calls[4:]), calls
"""


def test_the_timed_fit_compiles_nothing():
    done = subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
