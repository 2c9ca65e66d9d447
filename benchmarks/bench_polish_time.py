"""The polish's time with and without the palm freedom, beside the PSO fit's.

    taskset -c 0 python benchmarks/bench_polish_time.py [--frames 200] [--repeat 7]

ICVL's annotations of frames 100 onwards (``--frames`` of them) are fitted once with
``hybridfit.fit`` (hand27, uncalibrated, k = 1), then polished by
``hybridfit.fitting.refine.refine`` with the default bone freedom, alternately with the
rigid palm (0.7.0's default) and the default palm freedom. Prints the median wall time (s)
of each over ``--repeat`` alternations, their ratio, and the fit's time.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import hybridfit
from hybridfit.datasets.skeletons import dataset_model_config, skeleton
from hybridfit.fitting.refine import BONE_TOLERANCE, BONE_WEIGHT, PALM_TOLERANCE_MM, PALM_WEIGHT, refine

from bench_floor import annotations


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=7)
    a = ap.parse_args()
    names = skeleton("icvl").model_names
    truth = annotations("real", "icvl")[100:100 + a.frames]
    config = dataset_model_config("hand27", {}, "icvl")
    model = hybridfit.create("model", "hand27", config)
    given, ones = truth[:, :, None], np.ones(truth.shape[:2] + (1,))
    fit = lambda: hybridfit.fit(given, ones, joint_names=names, model="hand27", model_config=config)  # noqa: E731
    fit()  # compiles
    start = time.perf_counter()
    params = fit().params
    fit_s = time.perf_counter() - start
    times = {0.0: [], PALM_TOLERANCE_MM: []}
    for _ in range(a.repeat):
        for palm in times:
            start = time.perf_counter()
            refine(model, params, given, ones, names, bone_tolerance=BONE_TOLERANCE, bone_weight=BONE_WEIGHT,
                   palm_tolerance_mm=palm, palm_weight=PALM_WEIGHT)
            times[palm].append(time.perf_counter() - start)
    rigid, free = (float(np.median(v)) for v in times.values())
    print(f"{len(truth)} frames: fit {fit_s:.2f} s; polish, rigid palm {rigid:.2f} s, palm freedom "
          f"(+-{PALM_TOLERANCE_MM:g} mm) {free:.2f} s: {free / rigid:.2f}x")


if __name__ == "__main__":
    main()
