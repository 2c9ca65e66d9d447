"""``hybridfit show``: draw one frame of a data set with its joints (and optionally a fit's
estimate and the joint proposals) as a PNG."""

from __future__ import annotations

import numpy as np

from ..datasets.camera import xyz_to_uvd
from ..datasets.folder import load_dataset
from ..errors import HybridfitError
from ..io import load_npz, load_proposals
from ._common import check_image_format, declare_paths
from .evaluate import save_figure


def register(sub) -> None:
    p = sub.add_parser("show", help="draw a data set frame with its joints, skeleton and optional estimates as a PNG")
    p.add_argument("dataset", help="data set folder")
    p.add_argument("--frame", type=int, default=0, help="frame index (default 0)")
    p.add_argument("--out", required=True, help="output PNG")
    p.add_argument("--fits", metavar="NPZ", help="fit results with 'joints' (F, J, 3) mm (hybridfit fit --out)")
    p.add_argument("--proposals", metavar="NPZ", help="proposals (F, J, K, 3) mm with 'confidences' (F, J, K)")
    p.add_argument("--model", default="hand26", help="model whose skeleton to draw when the data set names none")
    declare_paths(p, inputs=("dataset", "--fits", "--proposals"), outputs=("--out",))
    p.set_defaults(func=run)


def _parents(ds, model_name: str):
    """(J,) parent indices from the data set's meta or a model with the same joints, else None."""
    if "parents" in ds.meta and len(ds.meta["parents"]) == len(ds.joint_names):
        return np.asarray(ds.meta["parents"])
    from ..registry import create

    try:
        model = create("model", model_name)
    except HybridfitError:
        return None
    return np.asarray(model.parents) if list(model.joint_names) == ds.joint_names else None


def _frame_array(path: str, data: dict, key: str, frames: int, joints: int, frame: int) -> np.ndarray:
    arr = data[key]
    if arr.shape[:2] != (frames, joints):
        raise HybridfitError(f"{path}: {key!r} has shape {arr.shape}, the data set has {frames} frames of {joints} joints")
    return arr[frame]


def _skeleton(ax, uv, parents, color: str, label: str, marker: str = "o", ls: str = "-") -> None:
    """Joints uv (J, 2+) as markers joined by bones (when parents are known)."""
    if parents is not None:
        for j, p in enumerate(parents):
            if p >= 0:
                ax.plot(uv[[p, j], 0], uv[[p, j], 1], color=color, lw=1.6, ls=ls, alpha=0.9)
    ax.scatter(uv[:, 0], uv[:, 1], s=28, color=color, marker=marker, edgecolors="white", linewidths=0.7,
               zorder=4, label=label)


def run(args) -> int:
    import matplotlib

    check_image_format(args.out)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ds = load_dataset(args.dataset)
    depth = ds.depth(args.frame).astype(float)
    f = args.frame % ds.frames
    J = len(ds.joint_names)
    parents = _parents(ds, args.model)
    truth = ds.joints_uvd[f]

    fig, ax = plt.subplots(figsize=(7.5, 6.2), dpi=110)
    cmap = matplotlib.colormaps["viridis_r"].with_extremes(bad="#f2f2f2")
    img = ax.imshow(np.ma.masked_equal(depth, 0), cmap=cmap, interpolation="nearest")
    fig.colorbar(img, ax=ax, fraction=0.046, pad=0.03).set_label("depth (mm)")
    _skeleton(ax, truth, parents, color="tab:red", label="ground truth")
    points = [truth[:, :2]]
    title = f"{ds.path.name}: frame {f} of {ds.frames}"
    if args.proposals:
        data = load_proposals(args.proposals)
        prop = _frame_array(args.proposals, data, "proposals", ds.frames, J, f)
        conf = _frame_array(args.proposals, data, "confidences", ds.frames, J, f)
        uv = xyz_to_uvd(prop.reshape(-1, 3), ds.intrinsics)
        size = 15 + 150 * conf.ravel() / max(conf.max(), 1e-12)
        ax.scatter(uv[:, 0], uv[:, 1], s=size, facecolors="none", edgecolors="tab:orange", linewidths=1.3,
                   zorder=3, label="proposals (size: confidence)")
        points.append(uv[:, :2])
    if args.fits:
        data = load_npz(args.fits)
        if "joints" not in data:
            raise HybridfitError(f"{args.fits}: missing key 'joints' (keys present: {', '.join(sorted(data)) or 'none'})")
        from .evaluate import points_array

        joints = {"joints": points_array(args.fits, data, "joints", allow_nan=True)}  # NaN: a failed fit
        est = _frame_array(args.fits, joints, "joints", ds.frames, J, f)
        uv = xyz_to_uvd(est, ds.intrinsics)
        _skeleton(ax, uv, parents, color="tab:blue", marker="s", ls="--", label="estimate")
        points.append(uv[:, :2])
        title += f"\nmean joint error {np.linalg.norm(est - ds.joints_xyz[f], axis=-1).mean():.1f} mm"
    # zoom on the hand: its pixels and every drawn point, with a margin
    vs, us = np.nonzero(depth)
    pts = np.concatenate(points + ([np.stack([us, vs], 1)] if len(us) else []))
    pts = pts[np.isfinite(pts).all(1)]
    lo, hi = pts.min(0) - 15, pts.max(0) + 15
    ax.set_xlim(max(lo[0], -0.5), min(hi[0], ds.intrinsics.width - 0.5))
    ax.set_ylim(min(hi[1], ds.intrinsics.height - 0.5), max(lo[1], -0.5))
    ax.set_xlabel("u (pixels)")
    ax.set_ylabel("v (pixels)")
    ax.set_title(title)
    ax.legend(loc="upper left", fontsize=8, framealpha=0.85)
    fig.tight_layout()
    save_figure(fig, args.out)
    print(f"wrote {args.out}")
    return 0
