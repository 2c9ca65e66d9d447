"""End to end: `hybridfit fit` as a user runs it, against the search alone at the same budget.

    python benchmarks/bench_end_to_end.py [--frames 2000] [--repeat 5] [--memory-frames 10000]
                                          [--stops 6] [--json benchmarks/results/end_to_end.json]

Every figure is a whole process (start-up, reading, fitting, writing), pinned to one core
(``sched_setaffinity``), on synthetic proposals (``hybridfit synth proposals``, k = 3):

- time per frame of the default fit (PSO stages, then the local Levenberg-Marquardt stage,
  all in the budget of 3400) and of the search alone at the same budget (the paper's schedule:
  ``--objective clamped-confidence --optimizer-config 'local_share = 0'``) on ``--frames``
  frames, runs alternated, medians and the ratio of the medians;
- the local stage's cost per frame against the PSO evaluations it replaces, inside one process
  (``hybridfit.fit`` of both, after a warm-up, medians);
- peak memory (the process's maximum resident set) of the default fit of ``--frames`` and
  of ``--memory-frames`` frames;
- stop latency: SIGTERM sent at spread moments of a ``--memory-frames`` fit; the time to
  exit (143, finished frames written), median and maximum.

The figures and their table go to ``--json`` (the results page's record).
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _util import json_argument, write_record  # noqa: E402


def pinned():
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})


def run(args: list[str], cwd: Path, stop_after_s: float | None = None) -> tuple[float, float, int, float]:
    """(wall s, peak resident MiB, exit code, s from the stop signal to exit) of `hybridfit ARGS`."""
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "hybridfit", *args], cwd=cwd, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, preexec_fn=pinned)
    latency = float("nan")
    if stop_after_s is not None:
        time.sleep(stop_after_s)
        sent = time.perf_counter()
        proc.send_signal(signal.SIGTERM)
    _, status, usage = os.wait4(proc.pid, 0)
    end = time.perf_counter()
    if stop_after_s is not None:
        latency = end - sent
    proc.returncode = os.waitstatus_to_exitcode(status)
    return end - start, usage.ru_maxrss / 1024.0, proc.returncode, latency


#: the search alone: the paper's objective and schedule, no local stage
SEARCH = ["--objective", "clamped-confidence", "--optimizer-config", "local_share = 0"]


def local_cost_ms(path: Path, repeat: int) -> float:
    """The local stage's cost per frame inside one process, against the PSO evaluations it
    replaces: median over ``repeat`` alternated runs of (default fit - search alone) / frames."""
    code = f"""
import time, numpy as np, hybridfit
d = np.load({str(path)!r}); P, C = d["proposals"], d["confidences"]
search = dict(objective="clamped-confidence", optimizer_config={{"local_share": 0.0}})
hybridfit.fit(P[:20], C[:20]); hybridfit.fit(P[:20], C[:20], **search)
out = []
for _ in range({repeat}):
    t = time.perf_counter(); hybridfit.fit(P, C); a = time.perf_counter() - t
    t = time.perf_counter(); hybridfit.fit(P, C, **search); b = time.perf_counter() - t
    out.append((a - b) / len(P) * 1e3)
print(sorted(out)[len(out) // 2])
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, preexec_fn=pinned)
    return float(done.stdout.split()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--memory-frames", type=int, default=10000)
    ap.add_argument("--stops", type=int, default=6, help="stop signals sent, at spread moments")
    json_argument(ap, "end_to_end")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for n in {a.frames, a.memory_frames}:
            subprocess.run([sys.executable, "-m", "hybridfit", "synth", "proposals", "--frames", str(n), "--out",
                            f"p{n}.npz"], cwd=work, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        fit = ["fit", f"p{a.frames}.npz", "--out", "fits.npz"]
        run(fit, work)  # compiles anything not yet cached
        default, search, memory = [], [], []
        for _ in range(a.repeat):  # alternated, so the machine's load falls on both alike
            wall, mib, code, _ = run(fit, work)
            assert code == 0
            default.append(wall / a.frames * 1e3)
            memory.append(mib)
            wall, _, code, _ = run(fit + SEARCH, work)
            assert code == 0
            search.append(wall / a.frames * 1e3)
        big = ["fit", f"p{a.memory_frames}.npz", "--out", "big.npz"]
        total, big_mib, code, _ = run(big, work)
        assert code == 0
        latencies = []
        for i in range(a.stops):  # from start-up to the end of the fit
            at = (i + 0.5) / a.stops * total
            _, _, code, latency = run(big, work, stop_after_s=at)
            if code == 143:  # ended by the signal (not finished before it)
                with np.load(work / "big.npz") as fits:
                    assert "failed" in fits.files
                latencies.append(latency)
        cost = local_cost_ms(work / f"p{a.frames}.npz", a.repeat)
    figures = {
        "frames": a.frames, "repeat": a.repeat,
        "default_ms_per_frame": statistics.median(default), "search_ms_per_frame": statistics.median(search),
        "ratio": statistics.median(default) / statistics.median(search),
        "local_stage_ms_per_frame": cost,
        "peak_mib": max(memory), "memory_frames": a.memory_frames, "peak_mib_memory_frames": big_mib,
        "stops": len(latencies), "stop_latency_median_s": statistics.median(latencies) if latencies else None,
        "stop_latency_max_s": max(latencies) if latencies else None,
    }
    print(f"hybridfit fit, {a.frames} synthetic frames, one core, whole process, medians of {a.repeat}:")
    print(f"  default (search + local stage) {figures['default_ms_per_frame']:.3f} ms/frame; the search alone "
          f"{figures['search_ms_per_frame']:.3f} ms/frame; ratio {figures['ratio']:.2f}x")
    print(f"  the local stage against the PSO evaluations it replaces: {cost:+.3f} ms/frame (in one process)")
    print(f"  peak memory: {figures['peak_mib']:.0f} MiB at {a.frames} frames, {big_mib:.0f} MiB at "
          f"{a.memory_frames} frames")
    if latencies:
        print(f"  stop (SIGTERM) to exit: median {figures['stop_latency_median_s']:.2f} s, max "
              f"{figures['stop_latency_max_s']:.2f} s over {len(latencies)} stops (exit 143, finished frames written)")
    write_record(a.json, tables(figures), figures=figures)


def tables(f: dict) -> dict:
    """The record's table of the figures ``f``."""
    stop = (f"median {f['stop_latency_median_s']:.2f} s, max {f['stop_latency_max_s']:.2f} s"
            if f["stops"] else "no stop landed before the end of the fit")
    return {"end_to_end": {"columns": ["figure", "value"], "rows": [
        ["default fit (search + local stage, budget 3400)", f"{f['default_ms_per_frame']:.3f} ms/frame"],
        ["the search alone (paper's schedule, budget 3400)", f"{f['search_ms_per_frame']:.3f} ms/frame"],
        ["ratio", f"{f['ratio']:.2f}x"],
        ["the local stage against the PSO evaluations it replaces, in one process",
         f"{f['local_stage_ms_per_frame']:+.3f} ms/frame"],
        [f"peak memory at {f['frames']} / {f['memory_frames']} frames",
         f"{f['peak_mib']:.0f} / {f['peak_mib_memory_frames']:.0f} MiB"],
        [f"SIGTERM to exit, {f['stops']} stops spread over a {f['memory_frames']}-frame run", stop],
    ]}}


if __name__ == "__main__":
    main()
