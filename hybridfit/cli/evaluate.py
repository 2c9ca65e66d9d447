"""``hybridfit evaluate``: error measures of fits, proposals or results files against ground truth.

Prints the mean joint error, the fingertip error, per-joint errors and success rates (the
share of frames whose worst joint is within a distance, 0-80 mm), and with ``--plot``
draws the success-rate curves of the evaluated file and every ``--compare`` file.
A proposals npz is evaluated twice: its top-1 proposal per joint and the Oracle (the
proposal closest to the truth). Ground truth comes from ``--ground-truth`` (a results
file, with ``--dataset``), a data set folder DATA, or the npz's own ``ground_truth``.
NaN or inf in any input is refused, naming the key and frame (except in the frames a fits
file marks ``failed``, which count as failures). For a fits npz it also lists the frames
whose fit is far from the proposals (fewer than half of the points within the fit's inlier
distance of one of their proposals).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..datasets.points import in_order
from ..errors import HybridfitError
from ..fitting.frames import INLIER_DISTANCE_MM
from ..io import atomic_path, load_npz
from ..plausible import check_hand_scale, check_unique_names
from ..text import check_name, plain
from ..metrics import SUCCESS_THRESHOLDS_MM, fingertips, inliers, joint_errors, oracle, success_rate
from ._common import FRAMES_HELP, check_image_format, declare_paths, frames_range, read_results

REPORTED = (20, 40, 80)


def points_array(path: str, data: dict, key: str, allow_nan=None) -> np.ndarray:
    """data[key] as (F, J, 3) float mm; refuses other shapes and NaN/inf, naming the key and
    the first bad frame (frames where ``allow_nan`` (F,) is True may be NaN: failed fits;
    ``allow_nan=True``: any frame)."""
    a = np.asarray(data[key])
    if a.ndim != 3 or a.shape[-1] != 3 or a.dtype.kind not in "iuf":
        raise HybridfitError(f"{path}: {key!r} must be numbers of shape (frames, points, 3), got {a.dtype} {a.shape}")
    a = a.astype(float)
    bad = ~np.isfinite(a).all(axis=(1, 2))
    check_hand_scale(a, path, key)  # metres would give 0.02 mm errors and 100 % success
    if allow_nan is True:
        return a
    if allow_nan is not None and np.shape(allow_nan) == bad.shape:
        bad &= ~np.asarray(allow_nan, bool)
    if bad.any():
        raise HybridfitError(f"{path}: {key!r} has NaN or inf values in frame {int(np.argmax(bad))} "
                             f"({int(bad.sum())} frames)")
    return a


def check_objective(path: str, data: dict, failed, F: int) -> None:
    """Refuse a fits file whose ``objective`` (the loss reached, per frame) is NaN or inf in a
    frame it does not mark ``failed``: no fit ends there (hybridfit raises a plugin's
    non-finite loss instead of storing it), so the file is damaged or not a fit's."""
    if "objective" not in data:
        return
    objective = np.asarray(data["objective"])
    if objective.shape != (F,) or objective.dtype.kind not in "iuf":
        raise HybridfitError(f"{path}: 'objective' must be {F} numbers (one per frame), got {objective.dtype} "
                             f"{objective.shape}")
    bad = ~np.isfinite(objective.astype(float))
    if failed is not None and np.shape(failed) == bad.shape:
        bad &= ~np.asarray(failed, bool)
    if bad.any():
        raise HybridfitError(f"{path}: 'objective' has NaN or inf values in frame {int(np.argmax(bad))} "
                             f"({int(bad.sum())} frames) not marked failed: not a fit's result (a damaged file?)")


def point_names(path: str, data: dict, J: int) -> list[str] | None:
    """The npz's joint_names (plain strings), checked against J points (unique, printable)."""
    if "joint_names" not in data:
        return None
    names = np.asarray(data["joint_names"])
    if names.ndim != 1 or names.dtype.kind not in "US" or len(names) != J:
        raise HybridfitError(f"{path}: 'joint_names' must be {J} strings, got {names.dtype} {names.shape}")
    check_unique_names(names, path)
    return [check_name(n, f"{path}: 'joint_names'") for n in names]


def load_points(path: str, dataset: str | None) -> list[tuple[str, np.ndarray, list[str] | None]]:
    """A fits/proposals npz or results file -> [(label, (F, J, 3) mm, names or None)]."""
    label = Path(path).name
    if path.endswith(".npz"):
        data = load_npz(path)
        if "joints" in data:
            failed = np.asarray(data["failed"], bool) if "failed" in data else None
            joints = points_array(path, data, "joints", failed)
            check_objective(path, data, failed, len(joints))
            return [(label, joints, point_names(path, data, joints.shape[1]))]
        if "proposals" in data:
            from ..io import load_proposals

            z = load_proposals(path)
            p, w = z["proposals"], z["confidences"]
            names = point_names(path, z, p.shape[1])
            top = np.take_along_axis(p, w.argmax(axis=-1)[..., None, None], axis=2)[:, :, 0]
            check_hand_scale(top, path, "proposals")
            out = [(f"{label} top-1", top, names)]
            if "ground_truth" in z:
                out.append((f"{label} Oracle", oracle(p, points_array(path, z, "ground_truth"), w), names))
            if "optimized" in z:
                out.append((f"{label} optimized", points_array(path, z, "optimized"), names))
            return out
        if "optimized" in data:
            pts = points_array(path, data, "optimized")
            return [(label, pts, point_names(path, data, pts.shape[1]))]
        raise HybridfitError(f"{path}: no 'joints', 'proposals' or 'optimized' key")
    if dataset is None:
        raise HybridfitError(f"{path}: a results text file needs --dataset (icvl, nyu or msra)")
    from ..datasets.skeletons import skeleton

    return [(label, read_results(path, dataset), list(skeleton(dataset).model_names))]


def far_frames(path: str) -> tuple[np.ndarray, float] | None:
    """Frames of a fits npz whose fit is far from the proposals: fewer than half of the
    points within the inlier distance of one of their proposals (``inliers`` as written by
    ``fit``, or computed from the file's proposals); (frames, distance mm) or None."""
    if not path.endswith(".npz"):
        return None
    data = load_npz(path)
    if "joints" not in data:
        return None
    joints = points_array(path, data, "joints", data.get("failed"))
    failed = np.asarray(data["failed"], bool) if "failed" in data else np.zeros(len(joints), bool)
    dist = np.asarray(data.get("inlier_distance_mm", INLIER_DISTANCE_MM))
    if dist.shape != () or dist.dtype.kind not in "iuf" or not 0 < dist < np.inf:
        raise HybridfitError(f"{path}: 'inlier_distance_mm' must be one positive number (mm), got {dist}")
    if "inliers" in data:
        count = np.asarray(data["inliers"])
    elif "proposals" in data and "confidences" in data:
        from ..io import load_proposals

        z = load_proposals(path)
        if z["proposals"].shape[:2] != joints.shape[:2]:
            raise HybridfitError(f"{path}: 'proposals' {z['proposals'].shape} do not match 'joints' {joints.shape}")
        count = inliers(joints, z["proposals"], z["confidences"], float(dist))
    else:
        return None
    if count.shape != failed.shape or count.dtype.kind not in "iu":
        raise HybridfitError(f"{path}: 'inliers' must be {len(failed)} integers, got {count.dtype} {count.shape}")
    Q, dist = joints.shape[1], float(dist)
    return np.flatnonzero((count < Q / 2) & ~failed), dist


def load_truth(args) -> tuple[np.ndarray, list[str] | None]:
    """Ground truth (F, J, 3) mm and its point names."""
    if args.ground_truth:
        if not args.dataset:
            raise HybridfitError("--ground-truth needs --dataset (icvl, nyu or msra)")
        from ..datasets.skeletons import skeleton

        return read_results(args.ground_truth, args.dataset), list(skeleton(args.dataset).model_names)
    if args.data:
        from ..datasets import open_dataset

        ds = open_dataset(args.data, args.dataset if args.dataset and Path(args.data).suffix != ".npz" else None)
        truth = points_array(str(args.data), {"joints_xyz": ds.joints_xyz}, "joints_xyz")
        return truth, list(ds.joint_names)
    if args.predictions.endswith(".npz"):
        data = load_npz(args.predictions)
        if "ground_truth" in data:
            truth = points_array(args.predictions, data, "ground_truth")
            return truth, point_names(args.predictions, data, truth.shape[1])
    raise HybridfitError("no ground truth: give DATA, --ground-truth LABELS, or an npz with 'ground_truth'")


def _skeleton(dataset):
    from ..datasets.skeletons import skeleton

    return skeleton(dataset)


def register(sub) -> None:
    p = sub.add_parser("evaluate", help="mean, fingertip and per-joint errors and success rates against ground truth")
    p.add_argument("predictions", metavar="FITS_OR_PROPOSALS", help="npz with joints or proposals, or a results file")
    p.add_argument("data", nargs="?", metavar="DATA", help="data set folder providing the ground truth")
    p.add_argument("--dataset", help="skeleton and camera convention of results files: icvl, "
                   "nyu, nyu36, msra, mediapipe, mano or a skeleton .toml file")
    p.add_argument("--ground-truth", metavar="LABELS", help="ground truth results file")
    p.add_argument("--compare", nargs="+", default=[], metavar="FILE", help="further results files or npz to compare")
    p.add_argument("--frames", type=frames_range, metavar="START:STOP",
                   help=f"frames of the ground truth to evaluate: {FRAMES_HELP} (default: all; inputs with all "
                   "frames are cut alike)")
    p.add_argument("--plot", metavar="OUT.png", help="draw the success-rate curves (a PNG, or another format matplotlib writes)")
    declare_paths(p, inputs=("predictions", "data", "--ground-truth", "--compare"), outputs=("--plot",))
    p.set_defaults(func=run)


def run(args) -> int:
    from ..io import frame_slice

    if args.plot:
        check_image_format(args.plot, "--plot")
    truth, truth_names = load_truth(args)
    n_truth = len(truth)
    sel = frame_slice(args.frames, n_truth)
    methods = []
    for path in [args.predictions, *args.compare]:
        for label, pts, names in load_points(path, args.dataset):
            first_len = len(pts) if path is args.predictions else first_len
            if len(pts) == len(truth):
                pts = pts[sel]  # else: already the selected frames
            if len(pts) != len(truth[sel]):
                raise HybridfitError(f"{path}: {len(pts)} frames, the ground truth has {len(truth[sel])}")
            by_name = names if truth_names is not None else None  # else: taken in order, if the counts match
            methods.append((label, in_order(pts, by_name, truth_names or [""] * truth.shape[1], path,
                                            "the ground truth")))
    truth = truth[sel]
    file_frames = np.arange(n_truth)[sel] if first_len == n_truth else np.arange(len(truth))  # the file's indices
    truth, methods = common_frames(truth, methods, {args.predictions: file_frames})
    names = truth_names or [f"joint {j}" for j in range(truth.shape[1])]
    tips = fingertips(names)
    if args.dataset and names == list(_skeleton(args.dataset).model_names):
        names = list(_skeleton(args.dataset).names)  # show the dataset's own point names
    rows, per_joint, curves = [], [], []
    for label, pts in methods:
        e = joint_errors(pts, truth)
        curve = success_rate(e, SUCCESS_THRESHOLDS_MM)
        curves.append((label, curve))
        per_joint.append(np.nanmean(e, axis=0))
        tip = f"{np.nanmean(e[:, tips]):.2f}" if tips else "-"
        rows.append([label, f"{np.nanmean(e):.2f}", tip] + [f"{curve[t]:.3f}" for t in REPORTED])
    print(f"{len(truth)} frames, {truth.shape[1]} points; errors in mm; success@D: the share of frames whose worst "
          "point is within D mm")
    _table(["method", "mean", "fingertips"] + [f"success@{t}" for t in REPORTED], rows)
    print()
    _table(["point"] + [m[0] for m in methods],
           [[n] + [f"{pj[j]:.2f}" for pj in per_joint] for j, n in enumerate(names)])
    report_far_frames(args.predictions, np.arange(n_truth)[sel], first_len == n_truth)
    if args.plot:
        plot_success(curves, args.plot, f"Success rate on {len(truth)} frames")
        print(f"plot -> {args.plot}")
    return 0


def common_frames(truth: np.ndarray, methods: list, chosen: dict) -> tuple[np.ndarray, list]:
    """The frames every method has an estimate for (a failed or interrupted fit has none):
    truth and methods cut to them, so that errors and success rates are over the same
    frames. Prints how many frames each method lacks (and why, for a fits npz)."""
    has = np.ones(len(truth), bool)
    for label, pts in methods:
        missing = ~np.isfinite(pts).all(axis=(1, 2))
        if missing.any():
            print(f"{label}: {int(missing.sum())} of {len(missing)} frames failed{_reasons(label, chosen, missing)}")
        has &= ~missing
    if has.all():
        return truth, methods
    if not has.any():
        raise HybridfitError("no frame has an estimate in every input: nothing to evaluate")
    print(f"errors and success rates below are over the {int(has.sum())} frames with an estimate in every input\n")
    return truth[has], [(label, pts[has]) for label, pts in methods]


def _reasons(label: str, chosen: dict, missing: np.ndarray) -> str:
    """' (3 interrupted, 1 other)' from a fits npz's error messages, for the evaluated file."""
    path = next((p for p in chosen if Path(p).name == label), None)
    if path is None or not path.endswith(".npz"):
        return ""
    data = load_npz(path)
    if "error_frames" not in data or "error_messages" not in data or len(data["error_frames"]) != len(
            data["error_messages"]):
        return ""
    frames = set(np.asarray(chosen[path])[missing].tolist())
    messages = [str(m) for f, m in zip(np.asarray(data["error_frames"]).tolist(), data["error_messages"]) if f in frames]
    stopped = sum(m == "interrupted" for m in messages)
    parts = ([f"{stopped} interrupted"] if stopped else []) + ([f"{len(messages) - stopped} other"]
                                                                 if len(messages) > stopped else [])
    return f" ({', '.join(parts)})" if parts else ""


def report_far_frames(path: str, chosen: np.ndarray, all_frames: bool) -> None:
    """Print the evaluated frames (ground-truth indices ``chosen``) whose fit is far from the
    proposals: a count and the first 10. ``all_frames``: the file has every ground-truth
    frame (else only the chosen ones)."""
    far = far_frames(path)
    if far is None:
        return
    idx, dist = far
    frames = idx[np.isin(idx, chosen)] if all_frames else chosen[idx[idx < len(chosen)]]
    if len(frames):
        shown = ", ".join(str(int(f)) for f in frames[:10]) + (", ..." if len(frames) > 10 else "")
        print(f"\n{len(frames)} frames whose fit is far from the proposals (fewer than half of the points within "
              f"{dist:g} mm of one of their proposals): {shown}")


def _table(header, rows) -> None:
    widths = [max(len(str(r[c])) for r in [header, *rows]) for c in range(len(header))]
    for r in [header, ["-" * w for w in widths], *rows]:
        print("  ".join(str(v).ljust(w) if c == 0 else str(v).rjust(w) for c, (v, w) in enumerate(zip(r, widths))))


def save_figure(fig, out: str) -> None:
    """Write a matplotlib figure atomically (an existing image is replaced only by a complete
    one; a failed write names the path) and close it."""
    import matplotlib.pyplot as plt

    try:
        with atomic_path(out) as tmp:
            fig.savefig(tmp, format=Path(out).suffix.lstrip(".").lower())
    finally:
        plt.close(fig)


def plot_success(curves, out: str, title: str) -> None:
    """Success-rate curves [(label, (81,))] over 0..80 mm as a PNG (labels and title as written:
    no mathtext, a lone surrogate as its escape)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.8), dpi=120)
    for label, curve in curves:
        ax.plot(SUCCESS_THRESHOLDS_MM, curve, label=plain(label, "utf-8"), linewidth=1.8)
    ax.set_xlabel("distance threshold D (mm)")
    ax.set_ylabel("share of frames with every joint within D")
    ax.set_title(plain(title, "utf-8"))
    ax.set_xlim(0, 80)
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    save_figure(fig, out)
