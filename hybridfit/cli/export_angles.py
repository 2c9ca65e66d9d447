"""``hybridfit export-angles``: fits (.npz) -> a CSV table of each frame's position,
orientation and joint angles in degrees (``hybridfit.fitting.angles``). An alias of
``hybridfit export --out FILE.csv``: both call ``export_angles``."""

from __future__ import annotations

from ..fitting.angles import export_angles
from ._common import declare_paths


def register(sub) -> None:
    p = sub.add_parser("export-angles",
                       help="write each frame's position, orientation and joint angles (degrees) as CSV "
                       "(the same as `hybridfit export --out FILE.csv`)")
    p.add_argument("fits", help="npz from `hybridfit fit` or `estimate` (params, parameter_names, failed)")
    p.add_argument("--out", required=True, help="CSV file: frame, failed, x_mm, y_mm, z_mm, qw, qx, qy, qz, then "
                   "<parameter name>_deg for every joint angle; a failed frame's cells are empty")
    p.add_argument("--model", help="the model that made a fits file without parameter_names (hybridfit 0.3.0 "
                   "and older), e.g. hand26")
    declare_paths(p, inputs=("fits",), outputs=("--out",))
    p.set_defaults(func=run)


def run(args) -> int:
    result = export_angles(args.fits, args.out, args.model)
    failed = int(result.failed.sum())
    print(f"wrote {len(result.failed)} frames ({failed} failed, marked) -> {args.out}")
    return 0
