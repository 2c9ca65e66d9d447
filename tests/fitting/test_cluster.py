"""Fits on a real dask.distributed cluster (a `dask scheduler` and two `dask worker` processes on
localhost, started and stopped here): bit for bit the fits of one process, a lost worker's
chunk run again."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import hybridfit
from hybridfit.errors import HybridfitError

pytest.importorskip("distributed", reason="dask.distributed is not installed: pip install -e '.[dask]'")
DASK = shutil.which("dask", path=str(Path(sys.executable).parent)) or shutil.which("dask")
pytestmark = pytest.mark.skipif(DASK is None, reason="the dask command is not installed: pip install -e '.[dask]'")


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """(address, [worker processes]) of a scheduler and two single-threaded workers."""
    port = _port()
    address = f"tcp://127.0.0.1:{port}"
    logs = tmp_path_factory.mktemp("dask")
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    scheduler = subprocess.Popen([DASK, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                                 stdout=subprocess.DEVNULL, stderr=open(logs / "scheduler.log", "wb"), env=env)
    workers = [subprocess.Popen([DASK, "worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard",
                                 "--name", f"w{i}"], stdout=subprocess.DEVNULL,
                                stderr=open(logs / f"worker{i}.log", "wb"), env=env) for i in range(2)]
    from distributed import Client

    client = Client(address, timeout=30)
    try:
        client.wait_for_workers(2, timeout=60)
    finally:
        client.close()
    yield address, workers
    for p in [*workers, scheduler]:
        p.send_signal(signal.SIGTERM)
    for p in [*workers, scheduler]:
        try:
            p.wait(15)
        except subprocess.TimeoutExpired:
            p.kill()


def _data(frames=24):
    return hybridfit.synthetic_proposals(frames, seed=4)


def _same(a, b):
    for key in ("params", "joints", "objective", "evaluations", "failed"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)


@pytest.mark.parametrize("optimizer, config", [("stepwise-pso", {}), ("stepwise", {"optimizer": "nlopt", "local_share": 0})])
def test_a_fit_on_the_cluster_is_the_local_fit_bit_for_bit(cluster, optimizer, config):
    """Lockstep batch steps and a callback solver (frame by frame) alike."""
    d = _data()
    kwargs = dict(budget=600, seed=3, optimizer=optimizer, optimizer_config=config)
    local = hybridfit.fit(d["proposals"], d["confidences"], **kwargs)
    remote = hybridfit.fit(d["proposals"], d["confidences"], scheduler=cluster[0], **kwargs)
    _same(local, remote)
    assert remote.schedule == local.schedule


def _kill_when_busy(address: str, name: str, worker, stop: threading.Event) -> None:
    """Kill ``worker`` (dask name ``name``) as soon as the scheduler says it is running a chunk."""
    from distributed import Client

    with Client(address, timeout=30) as client:
        while not stop.is_set():
            busy = client.processing()
            names = {a: w.get("name") for a, w in client.scheduler_info()["workers"].items()}
            if any(names.get(a) == name and tasks for a, tasks in busy.items()):
                worker.kill()
                return
            time.sleep(0.01)


def test_a_lost_workers_chunk_runs_again_on_the_other(cluster):
    d = _data(400)
    kwargs = dict(budget=3400, seed=5, optimizer="stepwise", optimizer_config={"optimizer": "nlopt", "local_share": 0})
    local = hybridfit.fit(d["proposals"], d["confidences"], **kwargs)
    address, workers = cluster
    stop = threading.Event()
    killer = threading.Thread(target=_kill_when_busy, args=(address, "w0", workers[0], stop), daemon=True)
    killer.start()
    try:
        remote = hybridfit.fit(d["proposals"], d["confidences"], scheduler=address, **kwargs)
    finally:
        stop.set()
        killer.join(30)
    assert workers[0].poll() is not None, "the worker was not killed during the fit"
    _same(local, remote)


def test_an_address_where_no_scheduler_answers_is_one_line(monkeypatch):
    from hybridfit import cluster as cluster_module

    monkeypatch.setattr(cluster_module, "CONNECT_TIMEOUT_S", 1)
    d = _data(2)
    with pytest.raises(HybridfitError, match=rf"--scheduler tcp://127.0.0.1:{(port := _port())}: no dask scheduler"):
        hybridfit.fit(d["proposals"], d["confidences"], budget=300, scheduler=f"tcp://127.0.0.1:{port}")
