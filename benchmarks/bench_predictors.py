"""How real predictors err, and whether the stress predictors err alike (ICVL frames 0-99 only).

    python benchmarks/bench_predictors.py [--frames 0:100]

On ICVL's tuning frames (0-99), the errors against the annotations of two real predictors
(LRF and the paper's top-1 proposals) and of the stress predictors
(``hybridfit.synthetic.predictors``, seed 0, 4 and 5 mm) drawn on the same annotations,
in both designs: heavy-tailed with per-predictor profiles (the default) and Gaussian
(``tail_sd = profile_sd = 0``). Per pair:

- their error correlation (x, y and z of every frame and point together);
- for each, the mean 3D point error over its median and the 95th percentile over the
  median (the tails);
- the spread of their per-point profiles: the standard deviation over the points of the log
  ratio of the two predictors' mean per-point errors, and its range.

The stress predictors' ``TAIL_SD`` and ``PROFILE_SD`` are set from these figures.

A second table fuses three predictors without a model (so without the model's floor): the
real ones (LRF, the paper's top-1 and the paper's fit) and the stress ones at 4, 5 and 6
mm, each design: the best input, their per-point median, and their mean weighted by the
confidences of ``hybridfit.agreement`` (estimated on these frames) with the sequence-level
confidences alone (``frame_reach = None``) and with the per-frame weights (the default).
Both tables also go to ``--json`` (default ``benchmarks/results/predictors.json``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import hybridfit
from hybridfit.datasets.results import read_xyz
from hybridfit.datasets.skeletons import dataset_model_config, skeleton
from hybridfit.agreement import agreement_confidences
from hybridfit.synthetic.predictors import predictor_errors

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _util import json_argument, table, table_record, write_record  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "icvl"


def statistics(a: np.ndarray, b: np.ndarray) -> list[str]:
    """Errors a, b (F, Q, 3) mm of two predictors -> the row of figures (see the module doc)."""
    cells = [f"{np.corrcoef(a.ravel(), b.ravel())[0, 1]:.2f}"]
    for e in (a, b):
        n = np.linalg.norm(e, axis=-1)
        cells.append(f"{n.mean():.2f}: {n.mean() / np.median(n):.2f} / {np.percentile(n, 95) / np.median(n):.2f}")
    ratio = np.log(np.linalg.norm(a, axis=-1).mean(0) / np.linalg.norm(b, axis=-1).mean(0))
    cells.append(f"{ratio.std():.3f} ({np.exp(ratio.min()):.2f}-{np.exp(ratio.max()):.2f})")
    return cells


def fusion(x: np.ndarray, truth: np.ndarray) -> list[str]:
    """Predictions x (F, Q, M, 3) and truth (F, Q, 3) mm -> mean 3D errors (mm): the best
    input, the per-point median, the agreement-weighted means (sequence / per frame)."""
    err = lambda p: np.linalg.norm(p - truth, axis=-1).mean()  # noqa: E731
    mean = lambda c: (x * (c / c.sum(-1, keepdims=True))[..., None]).sum(2)  # noqa: E731
    return [f"{min(err(x[:, :, m]) for m in range(x.shape[2])):.2f}", f"{err(np.median(x, axis=2)):.2f}",
            f"{err(mean(agreement_confidences(x, frame_reach=None))):.2f}", f"{err(mean(agreement_confidences(x))):.2f}"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", default="0:100", help="ICVL frames START:STOP (default 0:100, the tuning frames)")
    json_argument(ap, "predictors")
    a = ap.parse_args()
    frames = slice(*(int(v) for v in a.frames.split(":")))
    truth = read_xyz(DATA / "icvl_test_groundtruth_label.txt", "icvl")[frames]
    lrf = read_xyz(DATA / "lrf_cvpr14_predictions.txt", "icvl")[frames]
    top1 = np.load(DATA / "poier2015_proposals.npz")["proposals"][frames, :, 0].astype(np.float64)
    model = hybridfit.create("model", "hand26", dataset_model_config("hand26", {}, "icvl"))
    names = skeleton("icvl").model_names
    paper = np.load(DATA / "poier2015_proposals.npz")["optimized"][frames].astype(np.float64)
    rows = [["real: LRF / the paper's top-1", *statistics(lrf - truth, top1 - truth)]]
    fused = [["real: LRF, the paper's top-1, the paper's fit", *fusion(np.stack([lrf, top1, paper], 2), truth)]]
    for label, tails in (("stress, heavy tails and profiles (default)", {}),
                         ("stress, Gaussian", {"tail_sd": 0.0, "profile_sd": 0.0})):
        e = predictor_errors(model, names, len(truth), np.random.default_rng(0), **tails)
        rows.append([f"{label}, 4 / 5 mm", *statistics(e[0], e[1])])
        fused.append([f"{label}, 4 / 5 / 6 mm", *fusion((truth[None] + e).transpose(1, 2, 0, 3), truth)])
    errors = ["predictors", "correlation", "first: mean, mean/median / p95/median",
              "second: mean, mean/median / p95/median", "sd of log per-point ratio (range)"]
    fusing = ["three predictors", "best input", "per-point median", "weighted mean, sequence confidences",
              "weighted mean, per-frame weights"]
    print(table(errors, rows))
    print()
    print(table(fusing, fused))
    write_record(a.json, {"errors": table_record(errors, rows), "fused": table_record(fusing, fused)})


if __name__ == "__main__":
    main()
