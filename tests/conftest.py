"""Shared fixtures: plugins and small synthetic frames."""

from __future__ import annotations

import signal

import pytest

import hybridfit


def pytest_addoption(parser):
    parser.addoption("--fuzz-examples", type=int, default=None,
                     help="generated bad inputs per fuzz test (tests/cli/test_fuzz.py; default: a few, for CI)")


def pytest_configure(config):
    config.addinivalue_line("markers", "run_last: run after every other test (tests/test_install.py's slow ones)")


def pytest_collection_modifyitems(session, config, items):
    """tests/test_install.py's quick tests first and its slow ones (``run_last``) last: the
    fixture that builds the wheel's environment starts its compiled fit in the background
    (numba compiling every kernel from scratch, a minute or more of one core), and the rest of
    the suite runs meanwhile, on the other core."""
    last = [item for item in items if item.get_closest_marker("run_last")]
    first = [item for item in items if item.path.name == "test_install.py" and item not in last]
    items[:] = first + [item for item in items if item not in first and item not in last] + last


@pytest.fixture(scope="session", autouse=True)
def ctrl_c_raises():
    """Python's own Ctrl-C handler, in this process and the commands tests start: a process
    started in the background by a non-interactive shell inherits SIGINT ignored, Python then
    installs no handler, and the tests of stop signals would see Ctrl-C do nothing."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.fixture(scope="session")
def hand26():
    return hybridfit.create("model", "hand26")


@pytest.fixture(scope="session")
def clamped():
    return hybridfit.create("objective", "clamped-confidence")


@pytest.fixture(scope="session")
def frames():
    """8 synthetic frames with k = 3 noisy proposals and decoys."""
    return hybridfit.synthetic_proposals(8, k=3, seed=11)


@pytest.fixture(scope="session")
def exact_frames():
    """4 synthetic frames whose single proposal per joint is the true joint."""
    return hybridfit.synthetic_proposals(4, k=1, noise_mm=0.0, p_missing=0.0, seed=5)


def random_params(model, n, rng):
    """(n, P) parameters within the model's bounds (positions within +-200 mm)."""
    lower, upper = model.bounds()
    lower, upper = lower.copy(), upper.copy()
    lower[:3], upper[:3] = -200.0, 200.0
    upper[:3] += [0, 0, 600]
    return rng.uniform(lower, upper, size=(n, model.n_params))


@pytest.fixture
def interrupt_at(monkeypatch):
    """interrupt_at(frame): make hybridfit.fit raise KeyboardInterrupt when it reaches that frame
    (and skip the CLI's set-up check)."""
    from hybridfit.fitting import driver, frames as fitting

    real = fitting._fit_chunk
    real_prepare = driver.Driver.prepare

    def arm(frame: int) -> None:
        def chunk(spec, frames, *rest):
            if frames[0] == frame:
                raise KeyboardInterrupt
            return real(spec, frames, *rest)

        def prepare(fitter, frames, *rest):
            if frames[0] == frame:
                raise KeyboardInterrupt
            return real_prepare(fitter, frames, *rest)

        monkeypatch.setattr(fitting, "_fit_chunk", chunk)
        monkeypatch.setattr(driver.Driver, "prepare", prepare)
        monkeypatch.setattr(fitting, "CHUNK", 1)  # the driver, one frame per chunk
        # `hybridfit fit` checks the hand on a few frames first (fits of their own, numbered from 0): skipped here,
        # so that the frame counted is the main fit's
        import hybridfit.cli.fit as cli_fit

        monkeypatch.setattr(cli_fit, "check_hand_and_geometry", lambda args, data, names, plugins, dataset:
                            plugins["model_config"])

    return arm
