"""Run every benchmark, each writing its record, then rebuild docs/results.md.

    python benchmarks/run_all.py [--quick] [--studies] [--only NAME ...] [--list]

Runs the benchmarks of ``JOBS`` one after another from the repository's root, each writing
its record ``benchmarks/results/NAME.json``; ``--studies`` also runs every study of
``studies/`` (``hybridfit study``) and keeps its ``results.json`` as
``studies/results/NAME.json``. A job that fails is reported and the others still run; the
exit code is 1 if any failed. Then the page is rendered (``render_results.py``) from the
records, a failed job's earlier record (if any) still in place.

``--quick`` runs each job at tiny settings, a smoke test: its records and page go to a
temporary folder (or ``--out``), never to the committed ones. ``--only`` runs the jobs
named; ``--list`` prints every job's name and command.

A full run first deletes numba's cache files in the checkout (``hybridfit/`` and ``plugins/``):
numba re-compiles a cached function when its own file changes, not when a function it
inlines from another module does (the scorers inline the kinematics), so a cache older than
the source could be what the figures measure. The first job compiles again.
"""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _util import REPO, RESULTS, default_record  # noqa: E402

STUDY_RESULTS = REPO / "studies" / "results"


@dataclass(frozen=True)
class Job:
    """A benchmark (its commands; the last one writes the record) or a study (``study``)."""

    name: str
    steps: tuple[tuple[str, ...], ...]  # commands: a script (benchmarks/...) or hybridfit's; "{work}": a work folder
    quick: tuple[tuple[str, ...], ...] = ()  # the same at tiny settings (default: steps)
    study: bool = False
    pin: bool = False  # on one core, as ``taskset -c 0``
    env: dict = field(default_factory=dict)

    def commands(self, quick: bool = False) -> tuple[tuple[str, ...], ...]:
        return (self.quick or self.steps) if quick else self.steps


def bench(name: str, *args: str, quick: tuple[str, ...] = (), script: str | None = None, **kw) -> Job:
    """A one-command benchmark: ``benchmarks/bench_NAME.py ARGS`` (or ``script``)."""
    path = f"benchmarks/{script or f'bench_{name}.py'}"
    return Job(name, ((path, *args),), ((path, *quick),), **kw)


def study(path: Path) -> Job:
    """A study file's job: ``hybridfit study`` (``--quick`` into the work folder), its ``results.json`` kept."""
    return Job(path.stem, (("hybridfit", "study", f"studies/{path.name}", "--jobs", "2", "--cache", "study_out/cache"),),
               (("hybridfit", "study", f"studies/{path.name}", "--quick", "--jobs", "2", "--out",
                 f"{{work}}/{path.stem}", "--cache", "{work}/cache"),), study=True)


STRONG_QUICK = ("--data", "icvl", "--model", "hand29", "--frames", "10", "--calibrate", "0:30", "--test", "30:60")
FOREST = "benchmarks/bench_forest.py", "--train", "{work}/train", "--test", "{work}/test", "--out", "{work}/forest.npz"
JOBS: list[Job] = [
    bench("end_to_end", quick=("--frames", "50", "--repeat", "1", "--memory-frames", "200", "--stops", "1")),
    bench("strong", "--model", "hand27", "hand29", quick=STRONG_QUICK),
    bench("strong_tuning", "--data", "icvl", "--model", "hand27", "hand29", "--calibrate", "0:80", "--test", "80:100",
          script="bench_strong.py", quick=STRONG_QUICK),
    bench("icvl", quick=("--frames", "130", "--budget", "300", "--out", "{work}/icvl")),
    bench("icvl_rigid_hand", quick=("--frames", "130")),
    bench("core", pin=True, quick=("--frames", "20", "--seeds", "2")),
    bench("peers", pin=True, quick=("--frames", "4", "--budget", "300", "--seeds", "2")),
    bench("thirdparty", quick=("--frames", "20", "--repeat", "1")),
    Job("forest", (("hybridfit", "synth", "train", "--out", "{work}/train"), ("hybridfit", "synth", "test", "--out",
                                                                               "{work}/test"), FOREST),
        (("hybridfit", "synth", "train", "--frames", "100", "--out", "{work}/train"),
         ("hybridfit", "synth", "test", "--frames", "10", "--out", "{work}/test"),
         (*FOREST, "--config", '{"n_trees": 1, "max_depth": 8}', "--budget", "300"))),
    bench("render", env={"NUMBA_NUM_THREADS": "1"}, quick=("--frames", "20")),
    bench("depth_objective", pin=True),
    bench("alternatives", pin=True, quick=("--quick",)),
    bench("predictors", quick=("--frames", "0:20")),
    bench("calibrate", "--jobs", "2", quick=("--frames", "20", "--fresh", "10", "--skeletons", "icvl", "--jobs", "1")),
    bench("robust", "--jobs", "2", quick=("--skeletons", "icvl", "--frames", "10")),
    *(study(p) for p in sorted((REPO / "studies").glob("*.toml"))),
]


def record_path(job: Job, benchmarks: Path = RESULTS, studies: Path = STUDY_RESULTS) -> Path:
    """Where the job's record goes: ``benchmarks/NAME.json`` or, for a study, ``studies/NAME.json``."""
    return (studies if job.study else benchmarks) / f"{job.name}.json"


def shown(path: Path) -> str:
    """``path`` as seen from the repository's root."""
    return str(path.relative_to(REPO)) if path.is_relative_to(REPO) else str(path)


def script_argv(job: Job, step: tuple[str, ...], record: Path) -> list[str]:
    """The benchmark's last command, saying where its record goes unless that is its default."""
    if job.study or record == default_record(step[0]):
        return list(step)
    return [*step, "--json", shown(record)]


def command(job: Job) -> str:
    """The job's full command as a user types it from the repository's root."""
    def typed(step):
        words = ["python", *step] if step[0].endswith(".py") else list(step)
        return shlex.join(w.replace("{work}", "bench_out") for w in words)

    prefix = "".join(f"{k}={v} " for k, v in job.env.items()) + ("taskset -c 0 " if job.pin else "")
    steps = [*job.steps[:-1], tuple(script_argv(job, job.steps[-1], record_path(job)))]
    text = " && ".join(prefix + typed(step) for step in steps)
    if job.study:
        text += f" && cp study_out/{job.name}/results.json studies/results/{job.name}.json"
    return text


def _pin():
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})


def run_job(job: Job, record: Path, work: Path, quick: bool) -> int:
    """Run the job's commands (stopping at the first that fails) so that its record ends up
    at ``record``; its exit code."""
    env = {**os.environ, **job.env}
    record.parent.mkdir(parents=True, exist_ok=True)
    steps = [tuple(w.replace("{work}", str(work)) for w in step) for step in job.commands(quick)]
    steps[-1] = tuple(script_argv(job, steps[-1], record))
    for step in steps:
        argv = [sys.executable, *(["-m"] if step[0] == "hybridfit" else []), *step]
        code = subprocess.run(argv, cwd=REPO, env=env, preexec_fn=_pin if job.pin else None).returncode
        if code:
            return code
    if job.study:
        out = work / job.name if quick else REPO / "study_out" / job.name
        shutil.copyfile(out / "results.json", record)
    return 0


def clear_numba_caches() -> int:
    """Delete numba's cache files (.nbi, .nbc) under the checkout's packages; how many."""
    found = [f for d in ("hybridfit", "plugins") for ext in ("*.nbi", "*.nbc") for f in (REPO / d).rglob(ext)]
    for f in found:
        f.unlink(missing_ok=True)
    return len(found)


def main(argv: list[str] | None = None, jobs: list[Job] | None = None) -> int:
    jobs = JOBS if jobs is None else jobs
    names = [j.name for j in jobs]
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="jobs: " + ", ".join(names))
    ap.add_argument("--quick", action="store_true", help="tiny settings, records and page into a temporary folder")
    ap.add_argument("--studies", action="store_true", help="also run the studies (long at full settings)")
    ap.add_argument("--only", nargs="+", metavar="NAME", choices=names, help="run these jobs only")
    ap.add_argument("--out", metavar="DIR", help="with --quick: the folder for its records and page")
    ap.add_argument("--list", action="store_true", help="print each job's name and command, run nothing")
    a = ap.parse_args(argv)
    if a.out and not a.quick:
        ap.error("--out is for --quick runs (full runs write the committed records and docs/results.md)")
    if a.list:
        for job in jobs:
            print(f"{job.name}: {command(job)}")
        return 0
    chosen = [j for j in jobs if j.name in a.only] if a.only else [j for j in jobs if a.studies or not j.study]
    if a.quick:
        root = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="hybridfit-quick-"))
        benchmarks, studies, work, page = root / "benchmarks", root / "studies", root / "work", root / "results.md"
    else:
        benchmarks, studies, work, page = RESULTS, STUDY_RESULTS, REPO / "bench_out", None
        print(f"deleted {clear_numba_caches()} numba cache files: the first job compiles the current source")
    work.mkdir(parents=True, exist_ok=True)
    failed = []
    for i, job in enumerate(chosen, 1):
        print(f"[{i}/{len(chosen)}] {job.name}: {command(job)}{' (quick)' if a.quick else ''}", flush=True)
        start = time.perf_counter()
        try:
            code = run_job(job, record_path(job, benchmarks, studies), work, a.quick)
        except OSError as err:  # a missing results.json, a command that cannot start
            print(f"  {err}", flush=True)
            code = -1
        status = "done" if code == 0 else f"FAILED (exit {code})"
        print(f"[{i}/{len(chosen)}] {job.name}: {status} in {time.perf_counter() - start:.0f} s", flush=True)
        if code:
            failed.append(f"{job.name} (exit {code})")
    import render_results

    written = render_results.write(page, benchmarks, studies)
    print(f"page -> {written}" + (f" (records in {benchmarks.parent})" if a.quick else ""))
    if failed:
        print(f"{len(failed)} of {len(chosen)} jobs failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    print(f"all {len(chosen)} jobs done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
