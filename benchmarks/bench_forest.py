"""Joint-regression forest: training time and memory, proposal speed, and accuracy.

    hybridfit synth train --out /tmp/train && hybridfit synth test --out /tmp/test
    python benchmarks/bench_forest.py --train /tmp/train --test /tmp/test --out /tmp/forest.npz
    python benchmarks/bench_forest.py --forest /tmp/forest.npz --test /tmp/test   # reuse a forest

Prints (the machine is shared: medians, and CPU time next to wall time):
1. with --train: training the forest (default ForestConfig: the paper's 3 trees, depth 23)
   on all frames, wall and CPU time and peak resident memory;
2. the load time of the forest file;
3. proposals for one frame on one core at k = 3 (default |P~| = 200, stride 2, bandwidth 10 mm;
   --proposal-set, --stride, --bandwidth change them; median over test frames, wall and thread
   CPU time), then for all test frames in one call on 1 and on --jobs threads;
4. on the test sequence: the plain regression (top proposal per joint), the Oracle (the
   proposal closest to the truth among the top k, k = 1..5) and the fitted pose
   (hybridfit.fit, stepwise PSO, k = 3): mean joint error, fingertip error and success
   rates (share of frames whose worst joint is within the threshold).

The speed figures and the accuracy table also go to ``--json`` (default
``benchmarks/results/forest.json``).
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _util import json_argument, table, table_record, write_record  # noqa: E402

import hybridfit  # noqa: E402
from hybridfit.datasets.folder import load_dataset  # noqa: E402
from hybridfit.forest import Forest, ForestConfig, dataset_masks, train_forest_dataset  # noqa: E402
from hybridfit.metrics import fingertips, joint_errors, oracle, success_rate  # noqa: E402

THRESHOLDS = (20, 30, 40, 50, 80)


def row(name: str, predicted: np.ndarray, truth: np.ndarray, tips: np.ndarray) -> list:
    e = joint_errors(predicted, truth)
    return [name, float(e.mean()), float(e[:, tips].mean()), *[float(r) for r in success_rate(e, THRESHOLDS)]]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--train", help="training data set (trains a forest)")
    ap.add_argument("--out", default="/tmp/forest.npz", help="where the trained forest is written")
    ap.add_argument("--forest", help="an existing forest file (instead of --train)")
    ap.add_argument("--test", required=True, help="test data set (hybridfit synth test)")
    ap.add_argument("--frames", type=int, help="first N test frames only")
    ap.add_argument("--jobs", type=int, default=2, help="training threads and fitting processes")
    ap.add_argument("--budget", type=int, default=3400, help="objective evaluations per fitted frame")
    ap.add_argument("--config", default="{}", help="ForestConfig overrides as JSON")
    ap.add_argument("--stride", type=int, default=2, help="test-time pixel stride")
    ap.add_argument("--bandwidth", type=float, default=10.0, help="test-time mean-shift bandwidth, mm")
    ap.add_argument("--proposal-set", type=int, default=200, help="votes per joint into mean-shift (|P~|)")
    json_argument(ap, "forest")
    args = ap.parse_args()
    speed = []  # [measure, value] rows of the record

    if args.train:
        import json

        ds = load_dataset(args.train)
        grid = ds.meta.get("config", {})
        print(f"training grid {args.train}: viewpoint jitter {grid.get('viewpoint_jitter_deg', 0)} deg, position jitter "
              f"{grid.get('position_jitter_mm', 0)} mm, distance jitter {grid.get('distance_jitter_mm', 0)} mm")
        t0, c0 = time.perf_counter(), time.process_time()
        forest = train_forest_dataset(ds, ForestConfig(**json.loads(args.config)), jobs=args.jobs, progress=True)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        forest.save(args.out)
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        print(f"training: {len(ds)} frames, {forest.n_trees} trees, {len(forest.node_threshold)} nodes, "
              f"{len(forest.leaf_weights)} leaves: {wall:.0f} s wall, {cpu:.0f} s CPU on {args.jobs} threads, "
              f"peak RSS {peak:.0f} MiB -> {args.out}")
        speed.append([f"training on {len(ds)} frames, {args.jobs} threads: wall / CPU / peak memory",
                      f"{wall:.0f} s / {cpu:.0f} s / {peak:.0f} MiB"])
        args.forest = args.out
    t0 = time.perf_counter()
    forest = Forest.load(args.forest)
    print(f"load {args.forest} ({Path(args.forest).stat().st_size / 2**20:.0f} MiB): {time.perf_counter() - t0:.3f} s")

    test = load_dataset(args.test)
    seq = test.meta.get("config", {})
    if "max_tilt_deg" in seq:
        print(f"test sequence {args.test}: tilt <= {seq['max_tilt_deg']} deg, roll <= {seq['max_roll_deg']} deg, "
              f"position +-{seq['position_spread_mm']} mm, distance +-{seq['depth_spread_mm']} mm")
    opts = {"proposal_set": args.proposal_set, "stride": args.stride, "bandwidth_mm": args.bandwidth}
    idx = np.arange(len(test) if args.frames is None else min(args.frames, len(test)))
    depths = test.depths(idx)
    masks = dataset_masks(test, idx, depths)
    truth = np.asarray(test.joints_xyz)[idx]
    K = test.intrinsics

    # speed: one frame at a time, one core (the kernels are single-threaded)
    forest.propose(depths[:1], K, masks[:1])
    times, cpu = [], []
    for f in range(len(idx)):
        t, c = time.perf_counter(), time.thread_time()
        forest.propose(depths[f:f + 1], K, masks[f:f + 1], k=3, **opts)
        times.append(time.perf_counter() - t)
        cpu.append(time.thread_time() - c)
    print(f"proposals per {K.width}x{K.height} frame (k=3, |P~|={args.proposal_set}, stride {args.stride}, "
          f"bandwidth {args.bandwidth:g} mm, one core): median "
          f"{1000 * np.median(times):.2f} ms, 90th percentile {1000 * np.percentile(times, 90):.2f} ms "
          f"(CPU time: median {1000 * np.median(cpu):.2f} ms); foreground pixels per frame {masks.sum((1, 2)).mean():.0f}")
    speed.append([f"proposals per frame (k = 3, |P~| = {args.proposal_set}, one core): median / 90th percentile",
                  f"{1000 * np.median(times):.2f} / {1000 * np.percentile(times, 90):.2f} ms"])
    for jobs in sorted({1, args.jobs}):
        t = time.perf_counter()
        forest.propose(depths, K, masks, k=3, jobs=jobs, **opts)
        wall = time.perf_counter() - t
        print(f"proposals for all {len(idx)} frames in one call on {jobs} thread(s): {wall:.2f} s "
              f"({len(idx) / wall:.0f} frames/s)")
        speed.append([f"proposals for {len(idx)} frames in one call, {jobs} thread(s)", f"{len(idx) / wall:.0f} frames/s"])

    p5 = forest.propose(depths, K, masks, k=5, **opts)
    tips = fingertips(forest.joint_names)
    rows = [row("regression (top proposal)", p5.proposals[:, :, 0], truth, tips)]
    for k in range(1, 6):
        rows.append(row(f"oracle k={k}", oracle(p5.proposals[:, :, :k], truth), truth, tips))
    t0 = time.perf_counter()
    est = hybridfit.HybridEstimator(forest, k=3, proposal_set=args.proposal_set, stride=args.stride,
                                    bandwidth_mm=args.bandwidth, budget=args.budget, jobs=args.jobs)
    fitted = est.fit_proposals(hybridfit.forest.Proposals(p5.proposals[:, :, :3], p5.confidences[:, :, :3],
                                                          p5.empty, p5.joint_names), progress=True)
    rows.append(row(f"fitted (stepwise PSO, k=3, {args.budget} evals)", fitted.joints, truth, tips))
    print(f"fitting {len(idx)} frames: {time.perf_counter() - t0:.0f} s on {args.jobs} processes")
    print(f"\n{len(idx)} test frames of {args.test}; errors in mm, success = worst joint within the threshold\n")
    header = ["method", "mean error", "fingertip error", *[f"success@{t}" for t in THRESHOLDS]]
    print(table(header, rows))
    write_record(args.json, {"speed": table_record(["measure", "value"], speed), "accuracy": table_record(header, rows)},
                 test_frames=len(idx))
    return 0


if __name__ == "__main__":
    sys.exit(main())
