"""Speed of the rendered-depth objective, and the measurement that chose hybrid's weight.

    taskset -c 0 python benchmarks/bench_depth_objective.py            # renders per second, one core
    python benchmarks/bench_depth_objective.py --choose-weight --frames 40

1. Hypothesis renders per second of ``rendered-depth`` at 64x64 (and 32, 128) pixels over
   the hand box: batches of 64 perturbed test-sequence poses (FORTH's swarm), median of 7.
2. With --choose-weight: hybrid's depth_weight on synthetic proposals (k = 3, 5 mm noise,
   decoys, confidences sometimes wrong) of a TrackSeq-like sequence with seed 7, a sequence no
   study reports on, its depth rendered from the same poses; stepwise PSO, budget 3400.
   Prints mean and fingertip error per weight.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import hybridfit
from hybridfit.metrics import fingertips, joint_errors
from hybridfit.objective import Observation
from hybridfit.render import Renderer
from hybridfit.synthdata import sequence_poses

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from _util import median_time, table  # noqa: E402


def renders_per_second(model, poses, depth, intrinsics, resolution: int) -> float:
    obj = hybridfit.create("objective", "rendered-depth", {"resolution": resolution})
    rng = np.random.default_rng(0)
    rates = []
    for f in range(0, len(poses), max(1, len(poses) // 8)):
        loss = obj.bind_observed(None, None, Observation.from_depth(depth[f], intrinsics), model)
        X = np.repeat(poses[f:f + 1], 64, axis=0)
        X[:, 7:] += rng.normal(0, 0.15, (64, X.shape[1] - 7))
        X[:, :3] += rng.normal(0, 5, (64, 3))
        joints = model.forward(model.clip(X))
        loss(joints, None, joints)
        rates.append(64 / median_time(lambda: loss(joints, None, joints)))
    return float(np.median(rates))


def choose_weight(model, frames: int, weights: list[float]) -> None:
    poses = sequence_poses({"frames": frames, "seed": 7})
    truth = model.forward(poses)
    syn = hybridfit.synthetic_proposals(frames, k=3, seed=7)  # its noise, decoys and confidences
    props = truth[:, :, None] + (syn["proposals"] - syn["ground_truth"][:, :, None])
    renderer = Renderer(model)
    depth = renderer.render(poses)[0]
    obs = [Observation.from_depth(d, renderer.intrinsics) for d in depth]
    tips = fingertips(model.joint_names)
    rows = []
    for w in weights:
        res = hybridfit.fit(props, syn["confidences"], objective="hybrid", objective_config={"depth_weight": w},
                            observations=obs, budget=3400, seed=0, jobs=2)
        e = joint_errors(res.joints, truth)
        rows.append([w, float(e.mean()), float(e[:, tips].mean())])
    print(f"hybrid depth_weight on a synthetic sequence (seed 7, {frames} frames), stepwise PSO 3400:")
    print(table(["depth_weight", "mean error (mm)", "fingertip error (mm)"], rows))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--choose-weight", action="store_true", help="also measure hybrid's depth_weight")
    ap.add_argument("--frames", type=int, default=40, help="frames of the weight measurement (default 40)")
    ap.add_argument("--weights", type=float, nargs="+", default=[0.0, 0.5, 1.0, 2.0, 4.0, 8.0])
    args = ap.parse_args()
    model = hybridfit.create("model", "hand26")
    renderer = Renderer(model)
    poses = sequence_poses({"frames": 40})
    depth = renderer.render(poses)[0]
    rows = [[r, renders_per_second(model, poses, depth, renderer.intrinsics, r)] for r in (32, 64, 128)]
    print("rendered-depth, hypothesis renders per second (batches of 64, median):")
    print(table(["resolution (pixels per side)", "renders / s"], rows))
    if args.choose_weight:
        choose_weight(model, args.frames, args.weights)


if __name__ == "__main__":
    main()
