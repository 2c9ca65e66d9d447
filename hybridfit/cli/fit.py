"""``hybridfit fit``: fit the hand model to a proposals file."""

from __future__ import annotations

import sys

import numpy as np

from .. import fit as fit_frames
from ..datasets.skeletons import dataset_model_config, skeleton
from ..errors import HybridfitError
from ..io import load_proposals, save_npz
from ..metrics import summary
from ._common import add_fit_options, add_plugin_options, plugin_kwargs


def register(sub) -> None:
    p = sub.add_parser("fit", help="fit the hand model to joint proposals (.npz)")
    p.add_argument("proposals", help="npz with proposals (F,J,K,3) mm, confidences (F,J,K), optional joint_names, ground_truth")
    p.add_argument("--out", required=True, help="output npz: params, joints, objective, evaluations, joint_names")
    add_plugin_options(p)
    add_fit_options(p)
    p.add_argument("--dataset", help="icvl, nyu or msra: the proposals' skeleton when the npz has no joint_names "
                   "(and the dataset's derived points for hand26)")
    p.set_defaults(func=run)


def run(args) -> int:
    data = load_proposals(args.proposals)
    names = data.get("joint_names")
    plugins = plugin_kwargs(args)
    extra = {}
    if args.dataset:
        sk = skeleton(args.dataset)
        if names is None:
            if data["proposals"].shape[1] != len(sk):
                raise HybridfitError(f"{args.proposals}: {data['proposals'].shape[1]} points, "
                                     f"but the {sk.dataset} skeleton has {len(sk)}")
            names = sk.model_names
        plugins["model_config"] = dataset_model_config(plugins["model"], plugins["model_config"], sk.dataset)
        extra["dataset"] = np.asarray(sk.dataset)
    result = fit_frames(
        data["proposals"], data["confidences"],
        joint_names=None if names is None else list(names),
        budget=args.budget, seed=args.seed, jobs=args.jobs, search_radius_mm=args.search_radius,
        progress=sys.stderr.isatty(), **plugins,
    )
    save_npz(args.out, **result.to_npz(), **extra)
    F = len(result.failed)
    print(f"fitted {F - int(result.failed.sum())}/{F} frames -> {args.out}")
    for f, msg in sorted(result.errors.items())[:10]:
        print(f"  frame {f}: {msg}", file=sys.stderr)
    if "ground_truth" in data and F:
        s = summary(result.joints, data["ground_truth"])
        print("mean joint error {mean_error_mm:.2f} mm; success rate @20/40/80 mm: "
              "{success@20mm:.3f} / {success@40mm:.3f} / {success@80mm:.3f}".format(**s))
    if result.interrupted:
        print(f"interrupted: finished frames saved to {args.out}", file=sys.stderr)
        return 130
    return 1 if result.failed.all() and F else 0
