"""Speed and accuracy of the depth objectives.

    taskset -c 0 python benchmarks/bench_depth_objective.py

1. Hypothesis renders per second of ``rendered-depth`` at 64x64 (and 32, 128) pixels over
   the hand box: batches of 64 perturbed test-sequence poses (FORTH's swarm), 8 frames; the
   median over frames of the median of 15 timings, and of the fastest timing (the speed of
   an uncontended core, on a shared machine).
2. Hypotheses per second of ``hybrid``'s depth terms (:mod:`hybridfit.model.surface`): a batch
   of 29 (a palm stage's swarm: every cone moves) and of 20 with one finger moving (a finger
   stage's), CPU time.
3. CPU ms per frame of ``hybridfit.fit`` on 40 frames of the test sequence (proposals: the true
   joints plus 8 mm noise, k = 3, budget 3400), each method's ratio to Proposed (PSO on the
   proposals, the default schedule) the median over rounds of the ratio within a round, the
   methods alternated in each round; and each one's mean joint error on that sequence rendered
   clean, and stressed: sensor noise (:class:`hybridfit.synthetic.noise.SensorNoise`'s
   defaults) on the depth of a subject whose finger bones differ from the model's (each
   finger's scaled by 0.95 to 1.07), the proposals around the subject's joints, the fit with
   the default model. ``hybrid, rendered term (before)`` is the hybrid objective of
   hybridfit 0.13 (the proposal term + 16 x rendered-depth / 60, a swarm for its local stage).

hybrid's weights are measured by ``studies/hybrid_weight.toml``. The tables also go to
``--json`` (default ``benchmarks/results/depth_objective.json``).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import hybridfit
from hybridfit.fitting.tracking import track
from hybridfit.model.render import Renderer
from hybridfit.objective import Objective, Observation
from hybridfit.synthetic.noise import SensorNoise, apply_noise
from hybridfit.synthetic.poses import sequence_poses
from hybridfit_plugins.models.hand26 import BONE_NAMES

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from _util import json_argument, median_time, table, table_record, write_record  # noqa: E402

#: the stressed subject's finger bones, times the model's
BONE_SCALE = {"thumb": 1.06, "index": 0.96, "middle": 1.05, "ring": 0.95, "little": 1.07}


class RenderedHybrid(Objective):
    """hybrid as it was (hybridfit 0.13): clamped-confidence + 16 x rendered-depth / 60."""

    observes_depth = True
    additive = False

    def bind_observed(self, proposals, weights, observation, model):
        prop = hybridfit.create("objective", "clamped-confidence").bind(proposals, weights)
        depth = hybridfit.create("objective", "rendered-depth").bind_observed(proposals, weights, observation, model)
        return lambda points, subset, joints: prop(points, subset) + 16.0 / 60.0 * depth(points, subset, joints)


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


def surface_rates(model, poses, depth, intrinsics) -> list[list]:
    """hybrid's depth terms: [batch, hypotheses per second (CPU)] of a palm and a finger stage's batch."""
    obj = hybridfit.create("objective", "hybrid")
    rng = np.random.default_rng(0)
    rows = {"29, every cone moving (a palm stage)": [], "20, one finger moving (a finger stage)": []}
    for f in range(0, len(poses), max(1, len(poses) // 8)):
        terms = obj.bind_observed(np.zeros((model.n_joints, 1, 3)), np.zeros((model.n_joints, 1)),
                                  Observation.from_depth(depth[f], intrinsics), model).terms
        palm = np.repeat(poses[f:f + 1], 29, axis=0)
        palm[:, :3] += rng.normal(0, 5, (29, 3))
        palm[:, 7:] += rng.normal(0, 0.15, (29, palm.shape[1] - 7))
        finger = np.repeat(poses[f:f + 1], 20, axis=0)
        finger[:, 11:15] += rng.normal(0, 0.15, (20, 4))
        for name, X in zip(rows, (palm, finger)):
            joints = model.forward(model.clip(X))
            terms.losses(joints)
            rows[name].append(len(X) / median_time(lambda t=terms, j=joints: t.losses(j), repeat=15, number=20,
                                                   clock=time.process_time))
    return [[name, float(np.median(r))] for name, r in rows.items()]


def sequence(model, poses, stressed: bool):
    """(proposals (F, J, 3, 3), confidences, observations, ground truth (F, J, 3)) of the sequence
    rendered clean or stressed (see the module doc)."""
    subject = model
    if stressed:
        geometry = model.geometry()
        lengths = {n: float(v) for n, v in zip(geometry.names, geometry.values) if n in BONE_NAMES}
        subject = hybridfit.create("model", "hand26", {"bone_lengths": {
            name: round(v * BONE_SCALE[name.split("_")[0]], 2) for name, v in lengths.items()}})
    renderer = Renderer(subject)
    depth, parts = renderer.render(poses)
    if stressed:
        depth, parts = apply_noise(depth, parts, renderer.intrinsics, SensorNoise(), seed=1)
    truth = subject.forward(poses)
    rng = np.random.default_rng(1)
    props = truth[:, :, None] + rng.normal(0, 8, truth.shape[:2] + (3, 3))
    obs = [Observation.from_depth(d, renderer.intrinsics) for d in depth]
    return props, np.ones(props.shape[:3]), obs, truth


def per_frame(model, poses, rounds: int = 3) -> list[list]:
    """[method, CPU ms / frame, ratio to Proposed, mean error clean (mm), stressed (mm)]."""
    data = {kind: sequence(model, poses, kind == "stressed") for kind in ("clean", "stressed")}
    methods = {
        "Proposed (PSO on the proposals, the default schedule)": {},
        "hybrid, rendered term (before)": {"objective": RenderedHybrid()},
        "hybrid": {"objective": "hybrid"},
        "FORTH-like tracker (rendered-depth, PSO 64x30, 1920)": None,
    }

    def run(name, kind, frames=slice(None)):
        props, conf, obs, _ = data[kind]
        props, conf, obs = props[frames], conf[frames], obs[frames]
        if methods[name] is None:
            return track(props, conf, objective="rendered-depth", optimizer="pso", budget=1920, observations=obs,
                         optimizer_config={"particles": 64, "init_share": 1.0}, first_params=poses[0]).joints
        extra = {"observations": obs} if "objective" in methods[name] else {}
        return hybridfit.fit(props, conf, budget=3400, **methods[name], **extra).joints

    for name in methods:  # compiled and warm before timing
        run(name, "clean", slice(0, 2))
    times = {name: [] for name in methods}
    for _ in range(rounds):
        for name in methods:
            t = time.process_time()
            run(name, "clean")
            times[name].append((time.process_time() - t) / len(poses) * 1e3)
    base = np.array(times[next(iter(methods))])
    rows = []
    for name in methods:
        errors = [float(np.linalg.norm(run(name, kind) - data[kind][3], axis=-1).mean()) for kind in data]
        rows.append([name, float(np.median(times[name])), float(np.median(np.array(times[name]) / base)), *errors])
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    json_argument(ap, "depth_objective")
    ap.add_argument("--rounds", type=int, default=3, help="timing rounds of the fits (default 3)")
    a = ap.parse_args()
    model = hybridfit.create("model", "hand26")
    renderer = Renderer(model)
    poses = sequence_poses({"frames": 40})
    depth = renderer.render(poses)[0]
    rows = [[r, *renders_per_second(model, poses, depth, renderer.intrinsics, r)] for r in (32, 64, 128)]
    renders = ["resolution (pixels per side)", "renders / s (median)", "renders / s (fastest timing)"]
    print("rendered-depth, hypothesis renders per second (batches of 64):")
    print(table(renders, rows))
    surface = surface_rates(model, poses, depth, renderer.intrinsics)
    terms = ["batch", "hypotheses / s (CPU)"]
    print("\nhybrid's depth terms, hypotheses per second:")
    print(table(terms, surface))
    frames = per_frame(model, poses, a.rounds)
    columns = ["method", "CPU ms / frame", "x Proposed", "mean error, clean (mm)", "mean error, stressed (mm)"]
    print(f"\nper frame (40 frames, medians of {a.rounds} rounds) and accuracy:")
    print(table(columns, frames))
    write_record(a.json, {"renders": table_record(renders, rows), "surface": table_record(terms, surface),
                          "frames": table_record(columns, frames)})


if __name__ == "__main__":
    main()
