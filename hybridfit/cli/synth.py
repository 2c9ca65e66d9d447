"""``hybridfit synth``: generate synthetic data (``proposals``: proposal frames from the model;
``train``: the rendered training grid; ``test``: the rendered TrackSeq-like test sequence)."""

from __future__ import annotations

import sys

from ..io import save_npz
from ..synthetic.proposals import MAX_NOISE_MM, synthetic_proposals
from ._common import (DEFAULT_PLUGINS, declare_paths, load_model_toml, load_toml, number_in, positive_int, seed_int,
                      validate_settings)


def register(sub) -> None:
    p = sub.add_parser("synth", help="generate synthetic data")
    kinds = p.add_subparsers(dest="synth_command", metavar="KIND", required=True)
    q = kinds.add_parser("proposals", help="synthetic joint proposals generated from the hand model")
    q.add_argument("--out", required=True, help="output npz (a valid `hybridfit fit` input with ground truth)")
    q.add_argument("--frames", type=positive_int, default=100, metavar="N", help="frames to make (default 100)")
    q.add_argument("-k", type=positive_int, default=3, help="proposals per joint (default 3)")
    q.add_argument("--noise", type=number_in(0, MAX_NOISE_MM), default=5.0, metavar="MM",
                   help=f"proposal noise, mm per axis: 0 to {MAX_NOISE_MM:g} (a hand's size; default 5)")
    q.add_argument("--seed", type=seed_int, default=0, help="random seed, >= 0 (default 0)")
    q.add_argument("--model", help="hand model plugin (default: the one --model-config names, else hand26)")
    q.add_argument("--model-config", metavar="TOML", help="hand model settings file (`hybridfit calibrate` writes one "
                   "that names its model)")
    declare_paths(q, inputs=("--model-config",), outputs=("--out",))
    q.set_defaults(func=run_proposals)

    t = kinds.add_parser("train", help="rendered training grid: finger articulations x viewpoints (default 7168 frames)")
    t.add_argument("--frames", type=positive_int, metavar="N", dest="grid_frames",
                   help="frames to make: N of the grid's frames drawn at random (seeded by --seed) over every "
                   "articulation and viewpoint, in grid order (default: the whole grid, 7168 frames, 1.7 GB; "
                   "each frame takes 0.23 MB)")
    t.set_defaults(func=run_train)
    s = kinds.add_parser("test", help="rendered TrackSeq-like test sequence of natural motions")
    s.add_argument("--frames", type=positive_int, metavar="N", help="frames to make: the first N of the sequence "
                   "(default 400)")
    s.set_defaults(func=run_test)
    for c in (t, s):
        c.add_argument("--out", required=True, help="output data set folder: new or empty, or a data set (its files are replaced, "
                       "any other file there is kept); another folder is refused")
        c.add_argument("--config", metavar="TOML", help="settings file (keys of hybridfit.synthetic.config.GridConfig / SequenceConfig)")
        c.add_argument("--seed", type=seed_int, help="random seed, >= 0 (motions and noise; default 0)")
        c.add_argument("--distance", type=float, metavar="MM", help="palm distance from the camera, mm (default 400)")
        c.add_argument("--noise", action="store_true", help="add the default sensor noise model")
        c.add_argument("--model", help="hand model plugin (default: the settings file's, else hand26)")
        c.add_argument("--model-config", metavar="TOML", help="hand model settings (default: the settings file's)")
        declare_paths(c, inputs=("--config", "--model-config"), replaced_folders=("--out",))


def run_proposals(args) -> int:
    model, config = load_model_toml(args.model_config, args.model)
    data = synthetic_proposals(args.frames, k=args.k, noise_mm=args.noise, seed=args.seed,
                               model=model or DEFAULT_PLUGINS["model"], model_config=config)
    save_npz(args.out, **data)
    print(f"wrote {args.frames} synthetic frames (k={args.k}) -> {args.out}")
    return 0


def _config(cls, args):
    """The settings file with the command-line options on top."""
    from ..synthetic.config import parse_config

    base = load_toml(args.config)
    validate_settings(cls, base, args.config, f"synth {args.synth_command}")  # the file alone: its errors name it
    model, settings = load_model_toml(args.model_config, args.model)
    options = {"seed": args.seed, "distance_mm": args.distance, "frames": getattr(args, "frames", None),
               "noise": base.get("noise", {}) if args.noise else None, "model": model,
               "model_settings": settings if args.model_config else None}
    return parse_config(cls, base, **{k: v for k, v in options.items() if v is not None})


def run_train(args) -> int:
    from ..synthetic.config import GridConfig
    from ..synthetic.sets import make_train

    from ..synthetic.poses import grid_poses, grid_subset

    config = _config(GridConfig, args)
    n = len(grid_poses(config))
    frames = grid_subset(n, args.grid_frames, config.seed)
    path = make_train(args.out, config, frames=frames, progress=sys.stderr.isatty())
    print(f"wrote the training grid -> {path}" if frames is None else
          f"wrote {len(frames)} of the training grid's {n} frames -> {path}")
    return 0


def run_test(args) -> int:
    from ..synthetic.config import SequenceConfig
    from ..synthetic.sets import make_test

    path = make_test(args.out, _config(SequenceConfig, args), progress=sys.stderr.isatty())
    print(f"wrote the test sequence -> {path}")
    return 0
