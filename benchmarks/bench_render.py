"""Speed of the synthetic data pipeline: rendering, the training grid, bulk loading.

    NUMBA_NUM_THREADS=1 python benchmarks/bench_render.py [--frames 500] [--grid DIR]

Prints medians (the machine is shared):
1. rendering 320x240 depth + part labels on one core, frames per second, for training-grid
   poses (the first viewpoint, jittered, and all 7), test-sequence poses and random poses, and with the
   default sensor noise;
2. with --grid DIR: generating the whole default training grid (7168 frames) into DIR
   (poses, rendering, writing), then loading all its frames back: from the packed cache
   and decoding the PNGs.

The tables also go to ``--json`` (default ``benchmarks/results/render.json``).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time

import numpy as np

import hybridfit
from hybridfit.datasets.camera import Intrinsics
from hybridfit.datasets.folder import load_dataset
from hybridfit.synthetic.noise import SensorNoise, apply_noise
from hybridfit.model.render import Renderer
from hybridfit.synthetic.config import GridConfig
from hybridfit.synthetic.poses import grid_poses, sequence_poses
from hybridfit.synthetic.sets import make_train
from hybridfit.synthetic.proposals import random_poses

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from _util import json_argument, median_time, table, table_record, write_record  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=500, help="frames per render timing (default 500)")
    ap.add_argument("--grid", metavar="DIR", help="also generate the full training grid into DIR and load it")
    json_argument(ap, "render")
    args = ap.parse_args()
    model = hybridfit.create("model", "hand26")
    renderer = Renderer(model)
    n = args.frames
    grid = grid_poses()
    rng = np.random.default_rng(0)
    sets = {
        "training grid, first viewpoint": grid[::7][rng.permutation(1024)[:n]],
        "training grid, 7 viewpoints": grid[rng.permutation(len(grid))[:n]],
        "test sequence": sequence_poses({"frames": n}),
        "random poses (synthetic.py)": random_poses(model, n, rng),
    }
    renderer.render(grid[:2])  # compile / load numba's cache
    rows = []
    for name, params in sets.items():
        joints = model.forward(params)
        t = median_time(lambda: renderer.render_joints(joints), repeat=5)
        depth, _ = renderer.render_joints(joints)
        rows.append([name, n / t, 1e3 * t / n, float((depth > 0).sum((1, 2)).mean())])
    depth, parts = renderer.render_joints(model.forward(sets["test sequence"]))
    t = median_time(lambda: apply_noise(depth, parts, Intrinsics(), SensorNoise()), repeat=3)
    rows.append(["+ sensor noise only (numpy)", n / t, 1e3 * t / n, float("nan")])
    print(f"Rendering 320x240 depth + parts, {n} frames, one core (medians):\n")
    print(table(["poses", "frames/s", "ms/frame", "hand pixels"], rows))
    tables = {"render": table_record(["poses", "frames/s", "ms/frame", "hand pixels"], rows)}

    if args.grid:
        t0 = time.perf_counter()
        make_train(args.grid, GridConfig())
        t_make = time.perf_counter() - t0
        ds = load_dataset(args.grid)
        t_cache = median_time(lambda: (ds.depths(), ds.part_labels()), repeat=3)
        tmp = [args.grid.rstrip("/") + f"/{k}.npy" for k in ("depth", "parts")]
        for p in tmp:
            shutil.move(p, p + ".off")
        try:
            t_png = median_time(lambda: (ds.depths(), ds.part_labels()), repeat=3)
        finally:
            for p in tmp:
                shutil.move(p + ".off", p)
        print(f"\nTraining grid ({ds.frames} frames) generated and written in {t_make:.1f} s")
        loading = [["packed .npy cache", t_cache, 1e3 * t_cache / ds.frames],
                   ["PNG decoding (thread pool)", t_png, 1e3 * t_png / ds.frames]]
        print(table(["load all depths + part labels", "seconds", "ms/frame"], loading))
        tables["grid"] = table_record(["load all depths + part labels", "seconds", "ms/frame"], loading)
        tables["grid"]["rows"].insert(0, [f"generate and write the grid ({ds.frames} frames)", f"{t_make:.1f}", ""])
    write_record(args.json, tables)


if __name__ == "__main__":
    main()
