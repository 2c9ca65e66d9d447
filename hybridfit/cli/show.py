"""``hybridfit show``: draw a data set's frames with their joints (and optionally a fit's
estimate and the joint proposals): one frame as an image (``--frame N``), or a sequence as an
animated GIF (``--frames A:B --out anim.gif``, one GIF frame per data frame, Pillow)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..datasets.camera import xyz_to_uvd
from ..datasets.folder import load_dataset
from ..errors import HybridfitError
from ..io import atomic_path, frame_slice, load_npz, load_proposals
from ..text import plain
from ._common import FRAMES_HELP, _number, check_image_format, declare_paths, frames_range
from .evaluate import save_figure

#: pixels around the drawn points and the hand's depth pixels
MARGIN_PX = 15
#: the GIF frame rates written (frames per second): a GIF's delays are hundredths of a second, and
#: browsers play delays under 2 of them slower
GIF_FPS = (0.01, 50.0)


def gif_fps(text: str) -> float:
    """--fps: a frame rate a GIF holds (GIF_FPS)."""
    return _number(text, float, lambda v: GIF_FPS[0] <= v <= GIF_FPS[1],
                   f"GIF frames per second from {GIF_FPS[0]:g} to {GIF_FPS[1]:g}")


def register(sub) -> None:
    p = sub.add_parser("show", help="draw a data set frame (image) or frames A:B (animated GIF) with joints, "
                       "skeleton and optional estimates")
    p.add_argument("dataset", help="data set folder")
    p.add_argument("--frame", type=int, help="the frame to draw as an image (default 0)")
    p.add_argument("--frames", type=frames_range, metavar="START:STOP", help="frames to animate as a GIF, one GIF frame "
                   f"per data frame (--out must end in .gif): {FRAMES_HELP}")
    p.add_argument("--out", required=True, help="output image: PNG (or another format matplotlib writes) for "
                   "--frame, .gif for --frames")
    p.add_argument("--fps", type=gif_fps, default=10.0, help=f"GIF frames per second, from {GIF_FPS[0]:g} to "
                   f"{GIF_FPS[1]:g} (default 10)")
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


def _frames_array(path: str, data: dict, key: str, frames: int, joints: int) -> np.ndarray:
    arr = data[key]
    if arr.shape[:2] != (frames, joints):
        raise HybridfitError(f"{path}: {key!r} has shape {arr.shape}, the data set has {frames} frames of {joints} joints")
    return arr


def _skeleton(ax, uv, parents, color: str, label: str, marker: str = "o", ls: str = "-"):
    """Joints uv (J, 2+) as markers joined by bones (when parents are known); the legend
    handle: the marker on a line of the bones' style (the marker alone without bones)."""
    from matplotlib.lines import Line2D

    if parents is not None:
        for j, p in enumerate(parents):
            if p >= 0:
                ax.plot(uv[[p, j], 0], uv[[p, j], 1], color=color, lw=1.6, ls=ls, alpha=0.9)
    ax.scatter(uv[:, 0], uv[:, 1], s=28, color=color, marker=marker, edgecolors="white", linewidths=0.7, zorder=4)
    return Line2D([], [], color=color, lw=1.6, ls=ls if parents is not None else "none", marker=marker,
                  markersize=6, markeredgecolor="white", label=label)


class _Overlays:
    """What is drawn over the depth frames: ground truth, proposals and a fit, checked once."""

    def __init__(self, args, ds) -> None:
        J = len(ds.joint_names)
        self.proposals = self.confidences = self.fits = None
        if args.proposals:
            data = load_proposals(args.proposals)
            self.proposals = _frames_array(args.proposals, data, "proposals", ds.frames, J)
            self.confidences = _frames_array(args.proposals, data, "confidences", ds.frames, J)
        if args.fits:
            data = load_npz(args.fits)
            if "joints" not in data:
                raise HybridfitError(f"{args.fits}: missing key 'joints' (keys present: {', '.join(sorted(data)) or 'none'})")
            from .evaluate import points_array

            joints = {"joints": points_array(args.fits, data, "joints", allow_nan=True)}  # NaN: a failed fit
            self.fits = _frames_array(args.fits, joints, "joints", ds.frames, J)


def _uv(ds, overlays: _Overlays, f: int) -> dict[str, np.ndarray]:
    """Frame f's drawn points in pixels: 'truth' (J, 3) u, v, d where annotated,
    'proposals' (J * K, 3), 'estimate' (J, 3) where the fit did not fail."""
    out = {}
    if np.isfinite(ds.joints_uvd[f]).all():
        out["truth"] = ds.joints_uvd[f]
    if overlays.proposals is not None:
        out["proposals"] = xyz_to_uvd(overlays.proposals[f].reshape(-1, 3), ds.intrinsics)
    if overlays.fits is not None and np.isfinite(overlays.fits[f]).all():
        out["estimate"] = xyz_to_uvd(overlays.fits[f], ds.intrinsics)
    return out


def _extent(depth: np.ndarray, uv: dict[str, np.ndarray]) -> np.ndarray:
    """(2, 2) the lowest and highest (u, v) of the hand's depth pixels and the drawn points
    (NaN without any)."""
    vs, us = np.nonzero(depth)
    pts = np.concatenate([p[:, :2] for p in uv.values()] + [np.stack([us, vs], 1).astype(float)])
    pts = pts[np.isfinite(pts).all(1)]
    return np.stack([pts.min(0), pts.max(0)]) if len(pts) else np.full((2, 2), np.nan)


def _draw(fig, ax, ds, f: int, depth: np.ndarray, parents, overlays: _Overlays, extent: np.ndarray,
          depth_range=None) -> None:
    """Frame f on ax: depth, ground truth (where annotated), proposals, the fit; zoomed on
    ``extent`` (:func:`_extent`) with a margin."""
    import matplotlib

    cmap = matplotlib.colormaps["viridis_r"].with_extremes(bad="#f2f2f2")
    vmin, vmax = depth_range or (None, None)
    img = ax.imshow(np.ma.masked_equal(depth, 0), cmap=cmap, interpolation="nearest", vmin=vmin, vmax=vmax)
    fig.colorbar(img, ax=ax, fraction=0.046, pad=0.03).set_label("depth (mm)")
    uv = _uv(ds, overlays, f)
    handles = []
    title = f"{plain(ds.path.name, 'utf-8')}: frame {f} of {ds.frames}"  # a folder name drawn as written
    if "truth" in uv:
        handles.append(_skeleton(ax, uv["truth"], parents, color="tab:red", label="ground truth"))
    if "proposals" in uv:
        conf = overlays.confidences[f]
        size = 15 + 150 * conf.ravel() / max(conf.max(), 1e-12)
        handles.append(ax.scatter(uv["proposals"][:, 0], uv["proposals"][:, 1], s=size, facecolors="none",
                                  edgecolors="tab:orange", linewidths=1.3, zorder=3, label="proposals (size: confidence)"))
    if "estimate" in uv:
        handles.append(_skeleton(ax, uv["estimate"], parents, color="tab:blue", marker="s", ls="--", label="estimate"))
        if "truth" in uv:
            title += f"\nmean joint error {np.linalg.norm(overlays.fits[f] - ds.joints_xyz[f], axis=-1).mean():.1f} mm"
    elif overlays.fits is not None:
        title += "\nthe fit failed on this frame"
    W, H = ds.intrinsics.width, ds.intrinsics.height
    if np.isfinite(extent).all():
        lo, hi = extent[0] - MARGIN_PX, extent[1] + MARGIN_PX
        ax.set_xlim(max(lo[0], -0.5), min(hi[0], W - 0.5))
        ax.set_ylim(min(hi[1], H - 0.5), max(lo[1], -0.5))
    ax.set_xlabel("u (pixels)")
    ax.set_ylabel("v (pixels)")
    ax.set_title(title)
    if handles:
        ax.legend(handles=handles, loc="upper left", fontsize=8, framealpha=0.85)


def figure(ds, f: int, parents, overlays: _Overlays, dpi: int = 110, extent=None, depth_range=None):
    """One frame as a matplotlib figure, zoomed on the hand and everything drawn (or on ``extent``)."""
    import matplotlib.pyplot as plt

    depth = ds.depth(f).astype(float)
    fig, ax = plt.subplots(figsize=(7.5, 6.2), dpi=dpi)
    _draw(fig, ax, ds, f, depth, parents, overlays, _extent(depth, _uv(ds, overlays, f)) if extent is None else extent,
          depth_range)
    fig.tight_layout()
    return fig


def write_gif(out: str, ds, frames: range, parents, overlays: _Overlays, fps: float) -> None:
    """The frames as an animated GIF, one GIF frame each, with one view (zoom and depth
    colours) for the whole sequence; written atomically."""
    import matplotlib.pyplot as plt
    from PIL import Image

    extents, lows, highs = [], [], []
    for f in frames:  # first pass: the view that holds every frame
        depth = ds.depth(f)
        extents.append(_extent(depth, _uv(ds, overlays, f)))
        if (depth > 0).any():
            lows.append(depth[depth > 0].min())
            highs.append(depth[depth > 0].max())
    extent = np.stack([np.nanmin([e[0] for e in extents], axis=0), np.nanmax([e[1] for e in extents], axis=0)]) \
        if np.isfinite(extents).all(axis=(1, 2)).any() else np.full((2, 2), np.nan)
    depth_range = (float(min(lows)), float(max(highs))) if lows else None
    images = []
    for f in frames:
        fig = figure(ds, f, parents, overlays, dpi=80, extent=extent, depth_range=depth_range)
        fig.canvas.draw()
        rgb = np.asarray(fig.canvas.buffer_rgba())[..., :3]
        plt.close(fig)
        images.append(Image.fromarray(rgb).convert("P", palette=Image.ADAPTIVE))
    with atomic_path(out) as tmp, open(tmp, "wb") as fh:
        images[0].save(fh, format="GIF", save_all=True, append_images=images[1:], duration=int(round(1000 / fps)),
                       loop=0, disposal=1)


def run(args) -> int:
    import matplotlib

    gif = Path(args.out).suffix.lower() == ".gif"
    if not gif:
        check_image_format(args.out)
    matplotlib.use("Agg")

    if args.frames is not None and args.frame is not None:
        raise HybridfitError("give --frame N (one image) or --frames A:B (an animation), not both")
    if args.frames is not None and not gif:
        raise HybridfitError(f"--frames {args.frames}: an animation is written as a GIF: give --out NAME.gif "
                             "(or --frame N for one image)")
    ds = load_dataset(args.dataset)
    if args.frames is not None:
        frames = range(ds.frames)[frame_slice(args.frames, ds.frames)]
    else:
        frame = args.frame or 0
        ds.depth(frame)  # a frame out of range: refused, naming it
        frames = range(frame % ds.frames, frame % ds.frames + 1)
    parents = _parents(ds, args.model)
    overlays = _Overlays(args, ds)
    if gif:
        write_gif(args.out, ds, frames, parents, overlays, args.fps)
        span = f"frames {frames[0]} to {frames[-1]}" if len(frames) > 1 else f"frame {frames[0]}"
        print(f"wrote {len(frames)} GIF frames ({span}) -> {args.out}")
        return 0
    save_figure(figure(ds, frames[0], parents, overlays), args.out)
    print(f"wrote {args.out}")
    return 0
