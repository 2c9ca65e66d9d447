"""``hybridfit view``: a fits file as one self-contained HTML page with a rotatable 3D view
of the fitted hand (:mod:`hybridfit.exports.viewer`)."""

from __future__ import annotations

from ..exports.fitted import load_fitted
from ..exports.viewer import write_view
from ._common import declare_paths


def register(sub) -> None:
    p = sub.add_parser("view", help="write a self-contained HTML page with a rotatable 3D view of the fitted hand")
    p.add_argument("fits", help="npz from `hybridfit fit` or `estimate` (one that names its model)")
    p.add_argument("--out", required=True, help="HTML file; it loads nothing from the network")
    declare_paths(p, inputs=("fits",), outputs=("--out",))
    p.set_defaults(func=run)


def run(args) -> int:
    fitted = load_fitted(args.fits)
    write_view(args.out, fitted)
    failed = int(fitted.result.failed.sum())
    print(f"wrote {len(fitted.result.failed)} frames{f' ({failed} failed, not drawn)' if failed else ''} -> "
          f"{args.out}; open it in a web browser")
    return 0
