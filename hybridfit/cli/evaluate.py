"""``hybridfit evaluate``: error measures of fits, proposals or results files against ground truth.

Prints the mean joint error, the fingertip error, per-joint errors and success rates (the
share of frames whose worst joint is within a distance, 0-80 mm), and with ``--plot``
draws the success-rate curves of the evaluated file and every ``--compare`` file.
A proposals npz is evaluated twice: its top-1 proposal per joint and the Oracle (the
proposal closest to the truth). Ground truth comes from ``--ground-truth`` (a results
file, with ``--dataset``), a data set folder DATA, or the npz's own ``ground_truth``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import HybridfitError
from ..io import load_npz
from ..metrics import fingertips, joint_errors, oracle, success_rate

THRESHOLDS = np.arange(0, 81)
REPORTED = (20, 40, 80)


def load_points(path: str, dataset: str | None) -> list[tuple[str, np.ndarray, list[str] | None]]:
    """A fits/proposals npz or results file -> [(label, (F, J, 3) mm, names or None)]."""
    label = Path(path).name
    if path.endswith(".npz"):
        data = load_npz(path)
        names = [str(n) for n in data["joint_names"]] if "joint_names" in data else None
        if "joints" in data:
            return [(label, np.asarray(data["joints"], float), names)]
        if "proposals" in data:
            from ..objective import normalise_confidences

            p = np.asarray(data["proposals"], float)
            w = normalise_confidences(data["confidences"]) if "confidences" in data else np.ones(p.shape[:3])
            top = np.take_along_axis(p, w.argmax(axis=-1)[..., None, None], axis=2)[:, :, 0]
            out = [(f"{label} top-1", top, names)]
            if "ground_truth" in data:
                out.append((f"{label} Oracle", oracle(p, data["ground_truth"], w), names))
            if "optimized" in data:
                out.append((f"{label} optimized", np.asarray(data["optimized"], float), names))
            return out
        if "optimized" in data:
            return [(label, np.asarray(data["optimized"], float), names)]
        raise HybridfitError(f"{path}: no 'joints', 'proposals' or 'optimized' key")
    if dataset is None:
        raise HybridfitError(f"{path}: a results text file needs --dataset (icvl, nyu or msra)")
    from ..datasets.results import read_xyz
    from ..datasets.skeletons import skeleton

    return [(label, read_xyz(path, dataset), list(skeleton(dataset).model_names))]


def load_truth(args) -> tuple[np.ndarray, list[str] | None]:
    """Ground truth (F, J, 3) mm and its point names."""
    if args.ground_truth:
        if not args.dataset:
            raise HybridfitError("--ground-truth needs --dataset (icvl, nyu or msra)")
        from ..datasets.results import read_xyz
        from ..datasets.skeletons import skeleton

        return read_xyz(args.ground_truth, args.dataset), list(skeleton(args.dataset).model_names)
    if args.data:
        from ..datasets import open_dataset

        ds = open_dataset(args.data, args.dataset if args.dataset and Path(args.data).suffix != ".npz" else None)
        return np.asarray(ds.joints_xyz, float), list(ds.joint_names)
    if args.predictions.endswith(".npz"):
        data = load_npz(args.predictions)
        if "ground_truth" in data:
            names = [str(n) for n in data["joint_names"]] if "joint_names" in data else None
            return np.asarray(data["ground_truth"], float), names
    raise HybridfitError("no ground truth: give DATA, --ground-truth LABELS, or an npz with 'ground_truth'")


def aligned(pred, pred_names, truth, truth_names, where) -> np.ndarray:
    """Predictions in the truth's point order (by name when both have names)."""
    if len(pred) != len(truth):
        raise HybridfitError(f"{where}: {len(pred)} frames, the ground truth has {len(truth)}")
    if pred_names is None or truth_names is None:
        if pred.shape[1] != truth.shape[1]:
            raise HybridfitError(f"{where}: {pred.shape[1]} points, the ground truth has {truth.shape[1]}")
        return pred
    index = {n: i for i, n in enumerate(pred_names)}
    missing = [n for n in truth_names if n not in index]
    if missing:
        raise HybridfitError(f"{where}: no prediction for the ground truth's {', '.join(missing)}")
    return pred[:, [index[n] for n in truth_names]]


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
    p.add_argument("--frames", metavar="START:STOP",
                   help="evaluate only these frames of the ground truth (inputs with all frames are cut alike)")
    p.add_argument("--plot", metavar="OUT.png", help="draw the success-rate curves")
    p.set_defaults(func=run)


def run(args) -> int:
    from .calibrate import frame_slice

    truth, truth_names = load_truth(args)
    sel = frame_slice(args.frames, len(truth))
    methods = []
    for path in [args.predictions, *args.compare]:
        for label, pts, names in load_points(path, args.dataset):
            if len(pts) == len(truth):
                pts = pts[sel]  # else: already the selected frames
            methods.append((label, aligned(pts, names, truth[sel], truth_names, path)))
    truth = truth[sel]
    names = truth_names or [f"joint {j}" for j in range(truth.shape[1])]
    tips = fingertips(names)
    if args.dataset and names == list(_skeleton(args.dataset).model_names):
        names = list(_skeleton(args.dataset).names)  # show the dataset's own point names
    rows, per_joint, curves = [], [], []
    for label, pts in methods:
        e = joint_errors(pts, truth)
        curve = success_rate(e, THRESHOLDS)
        curves.append((label, curve))
        per_joint.append(np.nanmean(e, axis=0))
        tip = f"{np.nanmean(e[:, tips]):.2f}" if tips else "-"
        rows.append([label, f"{np.nanmean(e):.2f}", tip] + [f"{curve[t]:.3f}" for t in REPORTED])
    print(f"{len(truth)} frames, {truth.shape[1]} points; errors in mm; success = share of frames whose worst point is within")
    _table(["method", "mean", "fingertips"] + [f"success@{t}" for t in REPORTED], rows)
    print()
    _table(["point"] + [m[0] for m in methods],
           [[n] + [f"{pj[j]:.2f}" for pj in per_joint] for j, n in enumerate(names)])
    if args.plot:
        plot_success(curves, args.plot, f"Success rate on {len(truth)} frames")
        print(f"plot -> {args.plot}")
    return 0


def _table(header, rows) -> None:
    widths = [max(len(str(r[c])) for r in [header, *rows]) for c in range(len(header))]
    for r in [header, ["-" * w for w in widths], *rows]:
        print("  ".join(str(v).ljust(w) if c == 0 else str(v).rjust(w) for c, (v, w) in enumerate(zip(r, widths))))


def plot_success(curves, out: str, title: str) -> None:
    """Success-rate curves [(label, (81,))] over 0..80 mm as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.8), dpi=120)
    for label, curve in curves:
        ax.plot(THRESHOLDS, curve, label=label, linewidth=1.8)
    ax.set_xlabel("distance threshold D (mm)")
    ax.set_ylabel("share of frames with every joint within D")
    ax.set_title(title)
    ax.set_xlim(0, 80)
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
