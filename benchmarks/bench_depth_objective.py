"""Speed of the rendered-depth objective.

    taskset -c 0 python benchmarks/bench_depth_objective.py

Hypothesis renders per second of ``rendered-depth`` at 64x64 (and 32, 128) pixels over
the hand box: batches of 64 perturbed test-sequence poses (FORTH's swarm), 8 frames; the
median over frames of the median of 15 timings, and of the fastest timing (the speed of
an uncontended core, on a shared machine). Then seconds per frame of the FORTH-like
tracker, Proposed and hybrid.

hybrid's depth weight is measured by ``studies/hybrid_weight.toml``. The tables also go to
``--json`` (default ``benchmarks/results/depth_objective.json``).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import hybridfit
from hybridfit.objective import Observation
from hybridfit.model.render import Renderer
from hybridfit.synthetic.poses import sequence_poses
from hybridfit.fitting.tracking import track

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from _util import json_argument, median_time, table, table_record, write_record  # noqa: E402


def renders_per_second(model, poses, depth, intrinsics, resolution: int) -> tuple[float, float]:
    """(median, fastest) renders per second."""
    obj = hybridfit.create("objective", "rendered-depth", {"resolution": resolution})
    rng = np.random.default_rng(0)
    rates, best = [], []
    for f in range(0, len(poses), max(1, len(poses) // 8)):
        loss = obj.bind_observed(None, None, Observation.from_depth(depth[f], intrinsics), model)
        X = np.repeat(poses[f:f + 1], 64, axis=0)
        X[:, 7:] += rng.normal(0, 0.15, (64, X.shape[1] - 7))
        X[:, :3] += rng.normal(0, 5, (64, 3))
        joints = model.forward(model.clip(X))
        loss(joints, None, joints)
        times = [median_time(lambda: loss(joints, None, joints), repeat=1) for _ in range(15)]
        rates.append(64 / np.median(times))
        best.append(64 / np.min(times))
    return float(np.median(rates)), float(np.median(best))


def seconds_per_frame(model, poses, depth, intrinsics, frames: int = 8) -> list[list]:
    """Median seconds per frame of the FORTH-like tracker, Proposed and hybrid on test-sequence
    frames (proposals: the true joints plus 8 mm noise, k = 3)."""
    truth = model.forward(poses[:frames])
    rng = np.random.default_rng(1)
    props = truth[:, :, None] + rng.normal(0, 8, truth.shape[:2] + (3, 3))
    conf = np.ones(props.shape[:3])
    obs = [Observation.from_depth(d, intrinsics) for d in depth[:frames]]
    runs = {
        "FORTH-like tracker (rendered-depth, PSO 64x30, 1920)": lambda: track(
            props, conf, objective="rendered-depth", optimizer="pso", budget=1920, observations=obs,
            optimizer_config={"particles": 64, "init_share": 1.0}, first_params=poses[0]),
        "Proposed (clamped-confidence, stepwise PSO, 3400)": lambda: hybridfit.fit(props, conf, budget=3400),
        "hybrid (stepwise PSO, 3400)": lambda: hybridfit.fit(props, conf, objective="hybrid", budget=3400,
                                                              observations=obs),
    }
    return [[name, median_time(run, repeat=3) / frames] for name, run in runs.items()]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    json_argument(ap, "depth_objective")
    a = ap.parse_args()
    model = hybridfit.create("model", "hand26")
    renderer = Renderer(model)
    poses = sequence_poses({"frames": 40})
    depth = renderer.render(poses)[0]
    rows = [[r, *renders_per_second(model, poses, depth, renderer.intrinsics, r)] for r in (32, 64, 128)]
    renders = ["resolution (pixels per side)", "renders / s (median)", "renders / s (fastest timing)"]
    print("rendered-depth, hypothesis renders per second (batches of 64):")
    print(table(renders, rows))
    frames = seconds_per_frame(model, poses, depth, renderer.intrinsics)
    print("\nseconds per frame (median of 3 runs over 8 frames):")
    print(table(["method", "s / frame"], frames))
    write_record(a.json, {"renders": table_record(renders, rows),
                          "seconds": table_record(["method", "s / frame"], frames)})


if __name__ == "__main__":
    main()
