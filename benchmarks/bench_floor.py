"""Know the floor: how close the calibrated model can follow annotations, and what refining costs.

    python benchmarks/bench_floor.py [--real icvl nyu] [--stress icvl nyu nyu36 msra mediapipe mano]
                                     [--pool 0:100] [--frames 200] [--jobs 1] [--model hand26]
                                     [--subset START:STOP:STEP] [--design heavy gaussian]
                                     [--levels 4 5 6] [--palm 5:0.3 0:1]

Per dataset (real: ICVL's test annotations, NYU actor 2's, from ../shared/data; stress: a
``stress_proposals`` subject per skeleton, seed 3), ``hybridfit.fitting.calibrate`` with its
defaults calibrates the model on the annotations of the frames ``--pool`` (80 frames spanning
the pose range, 20 % held out, spread over the pool). On ``--frames`` frames outside the pool,
spread evenly over the rest of the sequence (a pool of the whole sequence: over calibration's
held-out frames), it then measures (mean 3D error, mm):

- the floor: the annotations themselves fitted (``hybridfit.fit`` with the defaults, then
  the least-squares polish with its default per-frame bone and palm freedom, as
  ``fitting.refine.fit_and_refine`` and ``hybridfit fit`` do; the fit alone in brackets);
- refining a strong predictor: three predictors at 4, 5 and 6 mm (``--levels``) with errors
  correlated as real ones are (``synthetic.predictors``, seed 0), in each ``--design``:
  ``heavy`` (the default: heavy tails, a profile per predictor) and ``gaussian``
  (``tail_sd = profile_sd = 0``, the design of 0.6.0 and before); the best alone fitted (k = 1), and the three fused
  (k = 3, the confidences ``proposals from-results`` gives them: from their agreement per
  point and per frame, ``hybridfit.agreement``; beside it, with the sequence-level
  confidences alone, ``frame_reach = None``) beside the best input and their per-point median;
- the model's part of the cost: the same errors added to the floor's fitted points (a
  truth the model can represent) and refined; what the fit costs there is the fit's part,
  the rest of the cost is the model's (it cannot follow the annotations closer than the
  floor).

Calibration's in-sample and held-out errors are printed beside them.

``--palm TOLERANCE_MM:WEIGHT ...`` polishes every fit with each palm freedom of the polish
(``refine``'s ``palm_tolerance_mm`` and ``palm_weight``; default: ``fit_and_refine``'s), a
row each; the PSO fits are shared (calibration uses the defaults).

``--subset`` keeps only those frames of the annotations before anything else (frame
numbers, ``--pool`` included, then count within the subset): the tuning data, ICVL frames
0-99 (``--subset 0:100 --pool 0:100``: measured on calibration's 20 held-out frames) and
every 20th NYU actor-2 frame (``--subset 0:5812:20 --pool 0:291``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import hybridfit
from hybridfit.datasets.results import read_xyz
from hybridfit.datasets.skeletons import dataset_model_config, skeleton
from hybridfit.agreement import agreement_confidences
from hybridfit.fitting.calibrate import calibrate
from hybridfit.fitting.refine import BONE_TOLERANCE, BONE_WEIGHT, PALM_TOLERANCE_MM, PALM_WEIGHT, refine
from hybridfit.synthetic.predictors import predictor_errors

from _util import table

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
REAL = {"icvl": DATA / "icvl" / "icvl_test_groundtruth_label.txt",
        "nyu": DATA / "nyu" / "nyu_actor2_groundtruth_label.txt"}
STRESS_FRAMES = 1000


def annotations(kind: str, dataset: str) -> np.ndarray:
    """(F, Q, 3) mm: a real dataset's test annotations or a stress subject's."""
    if kind == "real":
        return read_xyz(REAL[dataset], dataset)
    return hybridfit.stress_proposals(STRESS_FRAMES, dataset=dataset, k=1, seed=3)["ground_truth"]


_FITS: dict = {}


def fit_error(truth, proposals, confidences, names, model_name, settings, jobs,
              palm=(PALM_TOLERANCE_MM, PALM_WEIGHT)) -> tuple[float, float, np.ndarray]:
    """(fit, fit + polish) mean 3D error (mm) of fitting the proposals with the defaults (the
    polish's palm freedom: ``palm`` (tolerance mm, weight)), and the polished points (F, Q,
    3) mm."""
    key = (proposals.tobytes(), confidences.tobytes(), model_name, repr(settings))
    if key not in _FITS:  # one fit per input, polished with each palm setting
        _FITS[key] = hybridfit.fit(proposals, confidences, joint_names=names, model=model_name, model_config=settings,
                                   jobs=jobs)
    r = _FITS[key]
    model = hybridfit.create("model", model_name, settings)
    polished = refine(model, r.params, proposals, confidences, names, bone_tolerance=BONE_TOLERANCE,
                      bone_weight=BONE_WEIGHT, palm_tolerance_mm=palm[0], palm_weight=palm[1]).points(model, names)
    err = lambda joints: float(np.nanmean(np.linalg.norm(joints - truth, axis=-1)))  # noqa: E731
    return err(r.joints), err(polished), polished


DESIGNS = {"heavy": {}, "gaussian": {"tail_sd": 0.0, "profile_sd": 0.0}}


def evaluate(kind: str, dataset: str, pool: slice, frames: int, jobs: int, model_name: str,
             subset: slice = slice(None), designs=("heavy",), levels=(4.0, 5.0, 6.0),
             palms=((PALM_TOLERANCE_MM, PALM_WEIGHT),)) -> list[list]:
    sk = skeleton(dataset)
    names = sk.model_names
    truth = annotations(kind, dataset)[subset]
    inside = np.arange(len(truth))[pool]
    outside = np.setdiff1d(np.arange(len(truth)), inside)
    t = time.perf_counter()
    cal = calibrate(truth[inside], names, model=model_name, model_config=dataset_model_config(model_name, {}, dataset),
                    jobs=jobs)
    t = time.perf_counter() - t
    if not len(outside):  # the pool is the whole sequence: calibration's held-out frames
        outside = inside[cal.heldout_frames]
    test = outside[np.unique(np.linspace(0, len(outside) - 1, frames).round().astype(int))]
    gt = truth[test]
    ones = np.ones(gt.shape[:2] + (1,))
    model = hybridfit.create("model", model_name, cal.settings)
    err = lambda joints: float(np.linalg.norm(joints - gt, axis=-1).mean())  # noqa: E731
    rows = []
    for design in designs:
        errors = predictor_errors(model, names, len(test), np.random.default_rng(0), predictors=len(levels),
                                  error_mm=(levels[0], levels[-1]), **DESIGNS[design])
        preds = gt[None] + errors
        fused_in = preds.transpose(1, 2, 0, 3)
        inputs = [err(p) for p in preds]
        median = err(np.median(preds, axis=0))
        for palm in palms:
            fitted = lambda truth, proposals, confidences: fit_error(  # noqa: E731
                truth, proposals, confidences, names, model_name, cal.settings, jobs, palm)
            floor = fitted(gt, gt[:, :, None], ones)
            single = fitted(gt, preds[0][:, :, None], ones)
            fused = fitted(gt, fused_in, agreement_confidences(fused_in))
            sequence = fitted(gt, fused_in, agreement_confidences(fused_in, frame_reach=None))
            representable = floor[2]
            fit_part = fitted(representable, (representable + errors[0])[:, :, None], ones)[1] - float(
                np.linalg.norm(errors[0], axis=-1).mean())
            rows.append([kind, dataset, f"{pool.start}:{pool.stop}", len(test), f"{cal.error_after:.2f}",
                         f"{cal.error_heldout:.2f} ({len(cal.heldout_frames)})",
                         f"{cal.error_heldout / cal.error_after:.2f}", f"{palm[0]:g} / {palm[1]:g}",
                         f"{floor[1]:.2f} ({floor[0]:.2f})", design, f"{inputs[0]:.2f}",
                         f"{single[1]:.2f} ({single[0]:.2f})", f"{single[1] - inputs[0]:+.2f}",
                         f"{fit_part:+.2f} / {single[1] - inputs[0] - fit_part:+.2f}",
                         f"{fused[1]:.2f} ({fused[0]:.2f})", f"{sequence[1]:.2f}", f"{min(inputs):.2f}",
                         f"{median:.2f}", f"{t:.0f}"])
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--real", nargs="*", default=["icvl", "nyu"], choices=sorted(REAL))
    ap.add_argument("--stress", nargs="*", default=["icvl", "nyu", "nyu36", "msra", "mediapipe", "mano"])
    ap.add_argument("--pool", default="0:100", help="calibration frames START:STOP (default 0:100)")
    ap.add_argument("--frames", type=int, default=200, help="evaluation frames outside the pool")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--model", default="hand26", help="hand model plugin (default: hand26)")
    ap.add_argument("--subset", default="::", help="keep only these annotated frames START:STOP:STEP (default: all)")
    ap.add_argument("--design", nargs="+", default=["heavy"], choices=sorted(DESIGNS),
                    help="stress predictors' design(s) (default: heavy)")
    ap.add_argument("--levels", nargs="+", type=float, default=[4.0, 5.0, 6.0],
                    help="the stress predictors' mean errors (mm), evenly spaced, lowest first (default: 4 5 6)")
    ap.add_argument("--palm", nargs="+", default=[f"{PALM_TOLERANCE_MM:g}:{PALM_WEIGHT:g}"],
                    help="the polish's palm freedom(s) TOLERANCE_MM:WEIGHT, a row each (default: the polish's)")
    a = ap.parse_args()
    steps = np.diff(a.levels)
    if len(a.levels) < 2 or (steps <= 0).any() or not np.allclose(steps, steps[0]):
        ap.error(f"--levels: give two or more evenly spaced errors, lowest first, got {a.levels}")
    try:
        palms = [tuple(float(v) for v in p.split(":")) for p in a.palm]
        assert all(len(p) == 2 and p[0] >= 0 and p[1] >= 0 for p in palms)
    except (ValueError, AssertionError):
        ap.error(f"--palm: give TOLERANCE_MM:WEIGHT, both >= 0, got {a.palm}")
    start, stop = (int(v) for v in a.pool.split(":"))
    subset = slice(*(int(v) if v else None for v in a.subset.split(":")))
    rows = []
    for kind, datasets in (("real", a.real), ("stress", a.stress)):
        for dataset in datasets:
            for row in evaluate(kind, dataset, slice(start, stop), a.frames, a.jobs, a.model, subset, a.design,
                                tuple(a.levels), palms):
                rows.append(row)
                print(" | ".join(map(str, row)), flush=True)
    print(table(["data", "skeleton", "pool", "frames", "calibration in-sample", "held out (frames)", "ratio",
                 "palm freedom (mm / weight)", "floor (fit only)", "design", "predictor", "refined (fit only)", "cost",
                 "cost: fit / model", "fused (fit only)", "fused, sequence confidences", "best input",
                 "median", "calibration time (s)"], rows))


if __name__ == "__main__":
    main()
