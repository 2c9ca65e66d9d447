"""Stop signals reach a fit between generations, never inside compiled code (a handler that
raised inside numba's call machinery turned a SIGHUP into a SystemError traceback)."""

import os
import signal

import numpy as np
import pytest

import hybridfit
from hybridfit.fitting import driver, stops


def test_a_signal_inside_deferred_is_raised_by_check_only():
    with pytest.raises(KeyboardInterrupt):
        with stops.deferred():
            os.kill(os.getpid(), signal.SIGINT)  # recorded by the deferred handler, nothing raised here
            recorded = list(stops._pending)
            stops.check()
    assert len(recorded) == 1 and recorded[0][1] == signal.SIGINT
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored on leaving


def test_leaving_delivers_a_signal_that_came_after_the_last_check():
    with pytest.raises(KeyboardInterrupt):
        with stops.deferred():
            os.kill(os.getpid(), signal.SIGINT)


def test_a_signal_during_the_driver_interrupts_the_fit_cleanly(monkeypatch):
    """A SIGINT sent from inside a generation's scoring (where compiled code runs) stops the fit
    as an interrupt, with every frame marked: no SystemError."""
    d = hybridfit.synthetic_proposals(4, k=2, seed=1)
    real = driver.PointScorer.score
    sent = []

    def score(self, *args):
        if not sent:
            os.kill(os.getpid(), signal.SIGINT)  # raising here would be inside the scoring
            sent.append("the scoring went on")
        return real(self, *args)

    monkeypatch.setattr(driver.PointScorer, "score", score)
    result = hybridfit.fit(d["proposals"], d["confidences"], budget=200, seed=0)
    assert sent == ["the scoring went on"] and result.interrupted and result.failed.all()
    assert set(result.errors.values()) == {"interrupted"}
    assert np.isnan(result.params).all()


def test_a_stop_does_not_wait_for_the_worker_processes(monkeypatch):
    """On the process-pool path (an optimiser without batch steps, jobs > 1) a stop returns at
    once, its workers stopped, instead of waiting for the chunks they are fitting (here: 60 s)."""
    import threading
    import time

    from hybridfit.fitting import frames

    monkeypatch.setattr(frames, "_fit_chunk", _slow_chunk)
    d = hybridfit.synthetic_proposals(4, k=2, seed=1)
    threading.Timer(1.0, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
    start = time.monotonic()
    result = hybridfit.fit(d["proposals"], d["confidences"], optimizer="nlopt", budget=200, jobs=2, seed=0)
    assert result.interrupted and result.failed.all()
    assert time.monotonic() - start < 20


def _slow_chunk(*args):
    """The process-pool path's chunk, 60 s late (module level: the pool pickles it by name)."""
    import time

    from hybridfit.fitting.frames import _fit_chunk

    time.sleep(60)
    return _fit_chunk(*args)
