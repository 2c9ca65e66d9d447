"""``hybridfit export-results``: fits (.npz) -> the common results format of a dataset."""

from __future__ import annotations

import numpy as np

from ..datasets.points import in_order
from ..datasets.results import write_xyz
from ..datasets.skeletons import skeleton
from ..errors import HybridfitError
from ..io import atomic_path, load_npz
from ._common import declare_paths


def register(sub) -> None:
    p = sub.add_parser("export-results", help="write fitted joints in a dataset's common results format")
    p.add_argument("fits", help="npz from `hybridfit fit` (joints, joint_names)")
    p.add_argument("--dataset", required=True, help="skeleton and camera convention: icvl, nyu, "
                   "nyu36, msra, mediapipe, mano or a skeleton .toml file")
    p.add_argument("--out", required=True, help="results text file: one line per frame, J x (u, v, d)")
    declare_paths(p, inputs=("fits",), outputs=("--out",))
    p.set_defaults(func=run)


def run(args) -> int:
    from .evaluate import point_names, points_array

    data = load_npz(args.fits)
    if "joints" not in data:
        raise HybridfitError(f"{args.fits}: missing key 'joints' (is it a fit result?)")
    joints = points_array(args.fits, data, "joints", allow_nan=True)  # failed frames: refused below
    if not len(joints):
        raise HybridfitError(f"{args.fits}: 'joints' has no frames")
    names = point_names(args.fits, data, joints.shape[1])
    joints = in_order(joints, names, skeleton(args.dataset).model_names, args.fits, args.dataset)
    failed = ~np.isfinite(joints).all(axis=(1, 2))
    if failed.any():
        raise HybridfitError(f"{args.fits}: {int(failed.sum())} failed frames (first {int(np.argmax(failed))}) "
                             "cannot be written in the results format")
    with atomic_path(args.out) as tmp:
        write_xyz(tmp, joints, args.dataset)
    print(f"wrote {len(joints)} frames -> {args.out}")
    return 0
