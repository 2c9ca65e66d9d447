"""The floor and strong predictors refined, with the one rigid hand: calibrated on ground truth, self-calibrated, not.

    python benchmarks/bench_strong.py [--data icvl nyu] [--model hand27] [--frames 400]
                                      [--calibrate 0:100] [--test 100:] [--json benchmarks/results/strong.json]

Per real data set (ICVL's test annotations, NYU actor 2's, from ../shared/data): a strong
predictor, ``synthetic.predictors.predictor_errors`` at 5 mm (heavy tails, seed 0), of every
frame's annotations; ``--frames`` test frames spread evenly over the frames ``--test``
(default 100 to the end). The tuning data of hybridfit's defaults is ``--data icvl
--calibrate 0:80 --test 80:100`` (ICVL frames 0-99 only: self-calibration then sees the
predictions of those 100 frames alone).
Mean 3D error (mm) on the test frames of:

- the predictor itself, and refined by ``hybridfit.fit`` (k = 1, the default schedule) with
  the model (a) calibrated on the annotations of the frames ``--calibrate`` (default 0-99), (b)
  self-calibrated on the predictions of all frames (of frames 0 to the end of ``--test``) (``self_calibrate``, no ground truth),
  (c) as it is (the dataset's skeleton mapping only);
- the floor: the annotations themselves fitted with (a) and (b): how close the rigid
  calibrated hand can follow them.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import hybridfit
from hybridfit.datasets.results import read_xyz
from hybridfit.datasets.skeletons import dataset_model_config, skeleton
from hybridfit.fitting.calibrate import calibrate, self_calibrate
from hybridfit.synthetic.predictors import predictor_errors

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _util import json_argument, write_record  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
LABELS = {"icvl": DATA / "icvl" / "icvl_test_groundtruth_label.txt",
          "nyu": DATA / "nyu" / "nyu_actor2_groundtruth_label.txt"}


def measure(dataset: str, model: str, n_test: int, calib: slice, tested: slice) -> dict:
    truth = read_xyz(LABELS[dataset], dataset)
    truth = truth[:tested.stop]  # frames after the tested ones play no part (tuning data stays tuning data)
    names = list(skeleton(dataset).model_names)
    config = dataset_model_config(model, {}, dataset)
    F = len(truth)
    outside = np.arange(F)[tested]
    test = outside[np.unique(np.linspace(0, len(outside) - 1, min(n_test, len(outside))).round().astype(int))]
    hand = hybridfit.create("model", model, config)
    pred = truth + predictor_errors(hand, names, F, np.random.default_rng(0), predictors=1, error_mm=(5.0, 5.0))[0]
    ones = np.ones(pred.shape[:2] + (1,))
    err = lambda j: float(np.linalg.norm(j - truth[test], axis=-1).mean())  # noqa: E731

    def fitted(points, settings):
        return err(hybridfit.fit(points[test][:, :, None], ones[test], model=model, model_config=settings,
                                 joint_names=names).joints)

    t = time.perf_counter()
    gt = calibrate(truth[calib], names, model=model, model_config=config).settings
    gt_s = time.perf_counter() - t
    t = time.perf_counter()
    own = self_calibrate(pred[:, :, None], ones, names, model=model, model_config=config).settings
    own_s = time.perf_counter() - t
    out = {"dataset": dataset, "model": model, "frames": F, "test_frames": len(test), "predictor_mm": err(pred[test]),
           "refined_calibrated_mm": fitted(pred, gt), "refined_self_calibrated_mm": fitted(pred, own),
           "refined_uncalibrated_mm": fitted(pred, config), "floor_calibrated_mm": fitted(truth, gt),
           "floor_self_calibrated_mm": fitted(truth, own), "calibrate_s": gt_s, "self_calibrate_s": own_s}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", nargs="+", default=["icvl", "nyu"], choices=sorted(LABELS))
    ap.add_argument("--model", nargs="+", default=["hand27"])
    ap.add_argument("--frames", type=int, default=400, help="test frames, spread over frames 100 to the end")
    ap.add_argument("--calibrate", default="0:100", help="frames START:STOP whose annotations calibrate")
    ap.add_argument("--test", default="100:", help="frames START:STOP (STOP may be empty) the figures are measured on")
    json_argument(ap, "strong")
    a = ap.parse_args()
    span = lambda text: slice(*(int(v) if v else None for v in text.split(":")))  # noqa: E731
    calib, tested = span(a.calibrate), span(a.test)
    rows = []
    print("| data | model | predictor | refined: calibrated | self-calibrated | uncalibrated | floor: calibrated "
          "| self-calibrated |\n|---|---|---|---|---|---|---|---|")
    for dataset in a.data:
        for model in a.model:
            r = measure(dataset, model, a.frames, calib, tested)
            rows.append(r)
            p = r["predictor_mm"]
            print(f"| {dataset} | {model} | {p:.2f} | {r['refined_calibrated_mm']:.2f} "
                  f"({r['refined_calibrated_mm'] - p:+.2f}) | {r['refined_self_calibrated_mm']:.2f} "
                  f"({r['refined_self_calibrated_mm'] - p:+.2f}) | {r['refined_uncalibrated_mm']:.2f} | "
                  f"{r['floor_calibrated_mm']:.2f} | {r['floor_self_calibrated_mm']:.2f} |", flush=True)
    write_record(a.json, tables(rows), rows=rows)


NAMES = {"icvl": "ICVL", "nyu": "NYU actor 2"}


def tables(rows: list[dict]) -> dict:
    """The record's table of the measured ``rows``: errors in mm, a refined predictor's change beside it."""
    def refined(r, key):
        return f"{r[key]:.2f} ({r[key] - r['predictor_mm']:+.2f})"

    return {"strong": {"columns": ["data", "model", "predictor", "refined, calibrated", "refined, self-calibrated",
                                   "uncalibrated", "floor, calibrated / self"],
                       "rows": [[NAMES.get(r["dataset"], r["dataset"]), r["model"], f"{r['predictor_mm']:.2f}",
                                 refined(r, "refined_calibrated_mm"), refined(r, "refined_self_calibrated_mm"),
                                 f"{r['refined_uncalibrated_mm']:.2f}",
                                 f"{r['floor_calibrated_mm']:.2f} / {r['floor_self_calibrated_mm']:.2f}"]
                                for r in rows]}}


if __name__ == "__main__":
    main()
