"""ICVL benchmark: calibrate on 100 frames, then fit the ground truth, LRF and the paper's proposals.

    python benchmarks/bench_icvl.py [--data ../shared/data/icvl] [--out bench_out/icvl] [--jobs 2]
                                    [--d-max 40] [--budget 3400] [--frames N]

Every step fits the model `hybridfit calibrate` calibrates by default (hand27 since 0.7.0;
the model config names it, so every `fit` uses it). Runs exactly these commands (printed as
they run) and prints the tables:
(a) the model-fit floor: calibrate on frames 0:100 (the first 100 frames of sequence 1; the
    last 20 of them held out, their fit error printed beside the in-sample one), fit the
    ground truth of every other frame as k = 1 proposals;
(b) LRF's predictions refined by fitting them (k = 1) with the calibrated model;
(c) the paper's own proposals (poier2015_proposals.npz, k = 3) fitted with it;
(d) LRF fused with the paper's top-1 proposals (written as a results file): `proposals
    from-results` of both, fitted with the objective the file names;
(e) three estimates fused: LRF, the paper's top-1 and the paper's own fit (`optimized`),
    with the confidences `proposals from-results` gives three files (from their agreement,
    per point and per frame) and, for comparison, equal ones (`--confidences 1 1 1`);
with per-joint errors beside the paper's fitted model. Errors are over all 1596 frames
(as in the data README) and over the 1496 frames not used for calibration. ``--frames N`` uses
the first N frames of each input only (a smoke test). The tables also go to ``--json``
(default ``benchmarks/results/icvl.json``).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hybridfit.datasets.results import read_xyz, write_xyz
from hybridfit.datasets.skeletons import skeleton
from hybridfit.metrics import joint_errors, success_rate

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _util import json_argument, write_record  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
CALIB = "0:100"
TEST = slice(100, None)
HEADER = ["method", "mean (mm)", "fingertips (mm)", "success@20", "success@40", "success@80"]
TABLES: dict[str, dict] = {}  # the record's tables, as printed


def sh(*args: str) -> None:
    cmd = ["hybridfit", *args]
    print("$ " + " ".join(cmd), flush=True)
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "hybridfit", *args], check=True, stdout=subprocess.DEVNULL)
    print(f"  ({time.perf_counter() - t:.0f} s)", flush=True)


def row(label, pred, truth) -> list[str]:
    e = joint_errors(pred, truth)
    s = success_rate(e, (20, 40, 80))
    return [label, f"{np.nanmean(e):.2f}", f"{np.nanmean(e[:, list(skeleton('icvl').fingertips)]):.2f}",
            f"{s[0]:.3f}", f"{s[1]:.3f}", f"{s[2]:.3f}"]


def table(key, title, rows, header=HEADER):
    print(f"\n{title}\n")
    print("| " + " | ".join(header) + " |")
    print("|" + " --- |" * len(header))
    for r in rows:
        print("| " + " | ".join(r) + " |")
    TABLES[key] = {"title": title, "columns": list(header), "rows": rows}


def first_frames(data: Path, out: Path, n: int) -> Path:
    """A copy of the data folder's three inputs cut to their first ``n`` frames (in ``out``)."""
    cut = out / "first_frames"
    cut.mkdir(exist_ok=True)
    for name in ("icvl_test_groundtruth_label.txt", "lrf_cvpr14_predictions.txt"):
        (cut / name).write_text("".join((data / name).read_text().splitlines(keepends=True)[:n]))
    with np.load(data / "poier2015_proposals.npz") as z:
        np.savez(cut / "poier2015_proposals.npz", **{k: z[k][:n] for k in z.files})
    return cut


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(REPO.parent / "shared" / "data" / "icvl"))
    ap.add_argument("--out", default=str(Path(tempfile.gettempdir()) / "hybridfit_bench_icvl"))
    ap.add_argument("--jobs", default="2")
    ap.add_argument("--budget", default="3400")
    ap.add_argument("--d-max", type=float, default=40.0, help="clamped-confidence d_max in mm")
    ap.add_argument("--frames", type=int, help="the first N frames of each input only (a smoke test; default all)")
    json_argument(ap, "icvl")
    a = ap.parse_args()
    data, out = Path(a.data), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    if a.frames:
        data = first_frames(data, out, a.frames)
    gt, lrf, poier = data / "icvl_test_groundtruth_label.txt", data / "lrf_cvpr14_predictions.txt", \
        data / "poier2015_proposals.npz"
    objective = out / "objective.toml"
    objective.write_text(f"d_max_mm = {a.d_max}\n")
    # d_max is clamped-confidence's (the paper's proposals); fits of results files use the objective the file names
    fit = ["--dataset", "icvl", "--model-config", str(out / "model.toml"),
           "--budget", a.budget, "--jobs", a.jobs]

    sh("calibrate", "--dataset", "icvl", "--ground-truth", str(gt), "--frames", CALIB, "--out", str(out / "model.toml"),
       "--jobs", a.jobs)
    print("  calibration: " + " / ".join(  # the header: in-sample and held-out fit errors (frames 80-99 held out)
        line.lstrip("# ") for line in (out / "model.toml").read_text().splitlines() if line.startswith("# fit error")))
    sh("proposals", "from-results", "--dataset", "icvl", str(gt), "--frames", "100:", "--ground-truth", str(gt),
       "--out", str(out / "gt_test.npz"))
    sh("fit", str(out / "gt_test.npz"), *fit, "--out", str(out / "fit_gt.npz"))
    sh("proposals", "from-results", "--dataset", "icvl", str(lrf), "--ground-truth", str(gt), "--out", str(out / "lrf.npz"))
    sh("fit", str(out / "lrf.npz"), *fit, "--out", str(out / "fit_lrf.npz"))
    sh("export-results", str(out / "fit_lrf.npz"), "--dataset", "icvl", "--out", str(out / "lrf_fitted.txt"))
    sh("fit", str(poier), *fit, "--objective-config", str(objective), "--out", str(out / "fit_poier.npz"))
    sh("export-results", str(out / "fit_poier.npz"), "--dataset", "icvl", "--out", str(out / "poier_fitted.txt"))
    write_xyz(out / "poier_top1.txt", np.load(poier)["proposals"][:, :, 0].astype(float), "icvl")
    sh("proposals", "from-results", "--dataset", "icvl", str(lrf), str(out / "poier_top1.txt"), "--ground-truth",
       str(gt), "--out", str(out / "fused.npz"))
    sh("fit", str(out / "fused.npz"), *fit, "--out", str(out / "fit_fused.npz"))
    write_xyz(out / "poier_optimized.txt", np.load(poier)["optimized"].astype(float), "icvl")
    three = [str(lrf), str(out / "poier_top1.txt"), str(out / "poier_optimized.txt")]
    sh("proposals", "from-results", "--dataset", "icvl", *three, "--ground-truth", str(gt), "--out",
       str(out / "fused3.npz"))
    sh("fit", str(out / "fused3.npz"), *fit, "--out", str(out / "fit_fused3.npz"))
    sh("proposals", "from-results", "--dataset", "icvl", *three, "--confidences", "1", "1", "1", "--ground-truth",
       str(gt), "--out", str(out / "fused3_equal.npz"))
    sh("fit", str(out / "fused3_equal.npz"), *fit, "--out", str(out / "fit_fused3_equal.npz"))
    sh("evaluate", str(out / "poier_fitted.txt"), "--dataset", "icvl", "--ground-truth", str(gt),
       "--compare", str(poier), str(out / "lrf_fitted.txt"), str(lrf), "--plot", str(out / "success_icvl.png"))

    truth = read_xyz(gt, "icvl")
    z = np.load(poier)
    top1 = z["proposals"][:, :, 0].astype(float)  # sorted by confidence
    paper = z["optimized"].astype(float)
    fit_gt = np.load(out / "fit_gt.npz")["joints"]
    fit_lrf, fit_poier = read_xyz(out / "lrf_fitted.txt", "icvl"), read_xyz(out / "poier_fitted.txt", "icvl")
    raw_lrf = read_xyz(lrf, "icvl")
    fused = np.load(out / "fit_fused.npz")["joints"]
    fused3, fused3_equal = np.load(out / "fit_fused3.npz")["joints"], np.load(out / "fit_fused3_equal.npz")["joints"]
    z3 = np.load(out / "fused3.npz")
    weights = z3["confidences"] / z3["confidences"].sum(-1, keepdims=True)
    weighted = (z3["proposals"] * weights[..., None]).sum(2)

    table("floor", "(a) model-fit floor: calibrated model fitted to the ground truth (k = 1), frames 100-1595",
          [row("fit of the ground truth", fit_gt, truth[TEST])])
    for scope, name, sel in (("all", "all 1596 frames", slice(None)),
                             ("test", "frames 100-1595 (not used for calibration)", TEST)):
        table(f"lrf_{scope}", f"(b) LRF refined, {name}", [row("LRF (published)", raw_lrf[sel], truth[sel]),
                                                            row("LRF fitted (k = 1, ours)", fit_lrf[sel], truth[sel])])
        table(f"proposals_{scope}", f"(c) the paper's proposals, {name}", [
            row("top-1 proposals", top1[sel], truth[sel]),
            row("paper's fit (optimized)", paper[sel], truth[sel]),
            row("our fit of the proposals (k = 3)", fit_poier[sel], truth[sel])])
        table(f"fused2_{scope}", f"(d) LRF fused with the paper's top-1, {name}", [
            row("LRF (published)", raw_lrf[sel], truth[sel]), row("top-1 proposals", top1[sel], truth[sel]),
            row("their per-joint mean (not anatomically constrained)", (raw_lrf[sel] + top1[sel]) / 2, truth[sel]),
            row("the two fused by fitting (ours)", fused[sel], truth[sel])])
        table(f"fused3_{scope}", f"(e) LRF, the paper's top-1 and the paper's fit fused, {name}", [
            row("the paper's fit (optimized)", paper[sel], truth[sel]),
            row("their per-joint median (not anatomically constrained)",
                np.median(z3["proposals"][sel], axis=2), truth[sel]),
            row("their mean weighted by agreement (not anatomically constrained)", weighted[sel], truth[sel]),
            row("the three fused by fitting, equal confidences", fused3_equal[sel], truth[sel]),
            row("the three fused by fitting, confidences from agreement (ours, the default)", fused3[sel],
                truth[sel])])
    names = skeleton("icvl").names
    cols = {"paper's fit": paper, "our fit (c)": fit_poier, "top-1": top1, "LRF": raw_lrf, "LRF fitted (b)": fit_lrf}
    errs = {k: np.nanmean(joint_errors(v, truth), axis=0) for k, v in cols.items()}
    table("per_joint", "per-joint mean error (mm), all 1596 frames",
          [[n, *(f"{errs[k][j]:.2f}" for k in cols)] for j, n in enumerate(names)], ["joint", *cols])
    write_record(a.json, TABLES)


if __name__ == "__main__":
    main()
