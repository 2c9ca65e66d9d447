"""``hybridfit train``: train the random regression forest on a data set."""

from __future__ import annotations

import sys
import time

from ..datasets import open_dataset
from ..forest import ForestConfig, train_forest_dataset
from ._common import add_frames_option, declare_paths, load_toml, positive_int, seed_int, validate_settings
from ._forest import frame_indices


def register(sub) -> None:
    p = sub.add_parser("train", help="train the joint-regression forest on a data set (-> forest .npz)")
    p.add_argument("data", help="data-set folder (frames with depth, part labels and joints)")
    p.add_argument("--out", required=True, help="output forest file (.npz)")
    p.add_argument("--config", metavar="TOML", help="forest settings file (keys of hybridfit.forest.ForestConfig)")
    p.add_argument("--trees", type=positive_int, help="number of trees (default 3)")
    p.add_argument("--max-depth", type=positive_int, help="maximum tree depth (default 23)")
    p.add_argument("--pixels-per-frame", type=positive_int, help="training pixels per frame (default 400)")
    p.add_argument("--seed", type=seed_int, help="random seed, >= 0 (default 0)")
    add_frames_option(p, "frames to train on")
    p.add_argument("--jobs", type=positive_int, help="trees grown in parallel (default: the available cores)")
    declare_paths(p, inputs=("data", "--config"), outputs=("--out",))
    p.set_defaults(func=run)


def run(args) -> int:
    settings = load_toml(args.config)
    validate_settings(ForestConfig, settings, args.config, "the forest")  # the file alone: its errors name it
    for key, value in (("n_trees", args.trees), ("max_depth", args.max_depth),
                       ("pixels_per_frame", args.pixels_per_frame), ("seed", args.seed)):
        if value is not None:
            settings[key] = value
    config = ForestConfig(**settings)
    ds = open_dataset(args.data)
    idx = frame_indices(ds, args.frames)
    start = time.perf_counter()
    forest = train_forest_dataset(ds, config, idx, jobs=args.jobs, progress=sys.stderr.isatty())
    forest.save(args.out)
    print(f"trained {forest.n_trees} trees ({len(forest.node_threshold)} nodes, {len(forest.leaf_weights)} leaves) "
          f"on {len(idx)} frames in {time.perf_counter() - start:.1f} s -> {args.out}")
    return 0
