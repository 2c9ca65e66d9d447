"""``hybridfit study``: run a declarative study file (a sweep over settings and seeds)."""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import EXIT_INCOMPLETE, EXIT_OK, HybridfitError
from ._common import declare_paths, positive_int


def register(sub) -> None:
    p = sub.add_parser("study", help="run a study: a sweep of settings x seeds, results in SQLite, a report")
    p.add_argument("file", metavar="FILE", help="study file (TOML; see studies/)")
    p.add_argument("--out", help="output folder (default: study_out/<study file name>)")
    p.add_argument("--jobs", type=positive_int, default=1, help="parallel trials (workers)")
    p.add_argument("--executor", choices=("serial", "processes", "dask"),
                   help="where trials run (default: a local process pool, or serial for --jobs 1)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="dask scheduler address (default: a LocalCluster)")
    p.add_argument("--cache", metavar="DIR", help="cache folder for shared steps (default: OUT/cache)")
    p.add_argument("--quick", action="store_true", help="apply the study's [quick] overrides")
    p.add_argument("--report-only", action="store_true", help="rewrite the report from the database only")
    p.add_argument("--allow-large", action="store_true", help="run a study of more than 10,000 trials "
                   "(refused without it: such a sweep is usually a mistake, and its database grows by hundreds of MB)")
    p.add_argument("--optuna-storage", metavar="URL",
                   help="also record each trial in this Optuna storage as it finishes (e.g. sqlite:///live.db), so "
                   "`optuna-dashboard URL` shows the study while it runs; study.db stays the source of truth")
    p.add_argument("--keep-going", action="store_true",
                   help="record a trial that fails on a bug and go on (default: stop; bad input never stops)")
    declare_paths(p, inputs=("file",))  # --out and --cache: folders it adds files to
    p.set_defaults(func=run)


def run(args) -> int:
    from ..study import load_spec, run_study, write_report
    from ..study.expand import check_size

    if args.scheduler and args.executor != "dask":
        raise HybridfitError("--scheduler needs --executor dask")
    study = load_spec(args.file, quick=args.quick, allow_large=args.allow_large)  # a huge sweep: before expanding
    out = Path(args.out or Path("study_out") / (Path(args.file).stem + ("_quick" if args.quick else "")))
    if out.exists() and not out.is_dir():
        raise HybridfitError(f"--out {out}: is a file; a study writes a folder")
    if args.report_only:
        if not (out / "study.db").is_file() and not (out / "study.db").is_symlink():
            raise HybridfitError(f"{out}: no study.db to report from")
        print(f"report -> {write_report(out, study)}")
        return 0
    check_size(study, args.allow_large, args.file)
    executor = args.executor or ("processes" if args.jobs > 1 else "serial")
    s = run_study(study, out, jobs=args.jobs, executor=executor, scheduler=args.scheduler, cache_dir=args.cache,
                  progress=sys.stderr.isatty(), allow_large=args.allow_large,
                  keep_going=args.keep_going, optuna_storage=args.optuna_storage,  # bars on a terminal only
                  command=f"hybridfit study {args.file}" + (" --quick" if args.quick else ""))
    print(f"{s.total} trials: {s.skipped} already complete, {s.ran} run, {s.failed} failed -> {out}/report.md")
    return EXIT_INCOMPLETE if s.failed else EXIT_OK
