"""``hybridfit synth``: generate synthetic data (``proposals``: proposal frames from the model)."""

from __future__ import annotations

from ..io import save_npz
from ..synthetic import synthetic_proposals
from ._common import load_toml, positive_int


def register(sub) -> None:
    p = sub.add_parser("synth", help="generate synthetic data")
    kinds = p.add_subparsers(dest="synth_command", metavar="KIND", required=True)
    q = kinds.add_parser("proposals", help="synthetic joint proposals generated from the hand model")
    q.add_argument("--out", required=True, help="output npz (a valid `hybridfit fit` input with ground truth)")
    q.add_argument("--frames", type=positive_int, default=100)
    q.add_argument("-k", type=positive_int, default=3, help="proposals per joint (default 3)")
    q.add_argument("--noise", type=float, default=5.0, help="proposal noise, mm (default 5)")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--model", default="hand26")
    q.add_argument("--model-config", metavar="TOML")
    q.set_defaults(func=run_proposals)


def run_proposals(args) -> int:
    data = synthetic_proposals(args.frames, k=args.k, noise_mm=args.noise, seed=args.seed,
                               model=args.model, model_config=load_toml(args.model_config))
    save_npz(args.out, **data)
    print(f"wrote {args.frames} synthetic frames (k={args.k}) -> {args.out}")
    return 0
