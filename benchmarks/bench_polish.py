"""The polish's settings against the cost of refining, on the tuning data only.

    python benchmarks/bench_polish.py [--data real:icvl stress:nyu] [--jobs 1] [--model hand26]

Per data set (real ICVL: calibrated on frames 0-99 and measured on them, the frames one may
tune on; a stress subject (``stress_proposals``, seed 3): calibrated on frames 0-99 and
measured on 150 frames spread over 100-999), ``hybridfit.fitting.calibrate`` with its
defaults, then the annotations (the floor) and a 4 mm predictor with correlated errors
(``synthetic.predictors``, seed 0) are fitted once with ``hybridfit.fit`` and polished by
``hybridfit.fitting.refine.refine`` with each setting: bone tolerance and prior weight,
palm freedom (tolerance and prior weight), robust loss and its scale. Mean 3D error (mm).
"""

from __future__ import annotations

import argparse

import numpy as np

import hybridfit
from hybridfit.datasets.skeletons import dataset_model_config, skeleton
from hybridfit.fitting.calibrate import calibrate
from hybridfit.fitting.refine import BONE_TOLERANCE, BONE_WEIGHT, PALM_TOLERANCE_MM, PALM_WEIGHT, refine
from hybridfit.synthetic.predictors import predictor_errors

from _util import table
from bench_floor import annotations

SETTINGS = {
    "default (bones +-15 %, weight 0.3, palm +-5 mm, weight 0.3, soft_l1 at 10 mm)": {},
    "rigid palm (0.7.0's default)": {"palm_tolerance_mm": 0.0},
    "palm +-10 mm, weight 0.1": {"palm_tolerance_mm": 10.0, "palm_weight": 0.1},
    "palm weight 1": {"palm_weight": 1.0},
    "bone weight 0.1": {"bone_weight": 0.1},
    "bones +-25 %, weight 0.1": {"bone_tolerance": 0.25, "bone_weight": 0.1},
    "bone weight 1": {"bone_weight": 1.0},
    "bone weight 3": {"bone_weight": 3.0},
    "rigid bones": {"bone_tolerance": 0.0},
    "soft_l1 at 5 mm": {"scale_mm": 5.0},
    "soft_l1 at 20 mm": {"scale_mm": 20.0},
    "linear loss": {"loss": "linear"},
}
DEFAULT = {"bone_tolerance": BONE_TOLERANCE, "bone_weight": BONE_WEIGHT, "palm_tolerance_mm": PALM_TOLERANCE_MM,
           "palm_weight": PALM_WEIGHT}


def evaluate(kind: str, dataset: str, jobs: int, model_name: str = "hand26") -> dict[str, tuple[float, float]]:
    names = skeleton(dataset).model_names
    truth = annotations(kind, dataset)
    cal = calibrate(truth[:100], names, model=model_name, model_config=dataset_model_config(model_name, {}, dataset),
                    jobs=jobs)
    frames = np.arange(100) if kind == "real" else np.arange(100, 1000, 6)
    gt = truth[frames]
    model = hybridfit.create("model", model_name, cal.settings)
    predictor = gt + predictor_errors(model, names, len(frames), np.random.default_rng(0), predictors=1,
                                      error_mm=(4.0, 4.0))[0]
    ones = np.ones(gt.shape[:2] + (1,))
    starts = {key: hybridfit.fit(given[:, :, None], ones, joint_names=names, model=model_name,
                                 model_config=cal.settings, jobs=jobs).params
              for key, given in (("floor", gt), ("predictor", predictor))}
    out = {}
    for label, setting in SETTINGS.items():
        options = {**DEFAULT, **setting}
        out[label] = tuple(float(np.linalg.norm(refine(model, starts[key], given[:, :, None], ones, names, **options)
                                                .points(model, names) - gt, axis=-1).mean())
                           for key, given in (("floor", gt), ("predictor", predictor)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", nargs="+", default=["real:icvl", "stress:nyu"], help="KIND:SKELETON, KIND real or stress")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--model", default="hand26", help="hand model plugin (default: hand26)")
    a = ap.parse_args()
    results = {d: evaluate(*d.split(":"), a.jobs, a.model) for d in a.data}
    rows = [[label] + [f"{r[label][0]:.2f} / {r[label][1]:.2f} ({r[label][1] - 4.0:+.2f})" for r in results.values()]
            for label in SETTINGS]
    print(table(["polish setting"] + [f"{d}: floor / 4 mm predictor refined (cost)" for d in results], rows))


if __name__ == "__main__":
    main()
