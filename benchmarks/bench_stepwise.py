"""The paper's ablation on synthetic proposals: stepwise vs joint optimisation at equal budget.

    python benchmarks/bench_stepwise.py [--frames 200] [--jobs 2]

Paper setting: joint = one swarm of 91 particles x 91 generations (8281 evaluations) on
all 27 parameters; stepwise = 64 x 64 for the palm + 5 x 29 x 29 for the fingers (8301).
Also the default budget 3400 (default root share 0.3), other root shares, and the stepwise run
followed by a joint refinement (``refine_share``, an extension). Prints mean/median joint
error, the objective reached (-E, lower is better) and the success rate at 40 mm.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

import hybridfit
from hybridfit.metrics import joint_errors, success_rate

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from _util import table  # noqa: E402

VARIANTS = [  # the paper's schedule sets refine_share = 0; hybridfit's default refines (0.25)
    ("joint 91x91", 8281, {"schedule": "joint"}),
    ("stepwise 64x64 + 5 x 29x29 (the paper's)", 8301, {"stage_weights": [4096, 841, 841, 841, 841, 841],
                                                       "refine_share": 0.0}),
    ("stepwise 8301 + refine 0.25", 8301, {"stage_weights": [4096, 841, 841, 841, 841, 841]}),
    ("joint 3400", 3400, {"schedule": "joint"}),
    ("stepwise 3400 (the paper's schedule, root share 0.3)", 3400, {"refine_share": 0.0}),
    ("stepwise 3400, root share 0.5", 3400, {"root_share": 0.5, "refine_share": 0.0}),
    ("stepwise 3400, root share 0.7", 3400, {"root_share": 0.7, "refine_share": 0.0}),
    ("stepwise 3400 + refine 0.25 (default)", 3400, {}),
    ("joint 1000", 1000, {"schedule": "joint"}),
    ("stepwise 1000 (the paper's schedule)", 1000, {"refine_share": 0.0}),
    ("stepwise 1000 + refine 0.25 (default)", 1000, {}),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=2015)
    args = parser.parse_args()
    data = hybridfit.synthetic_proposals(args.frames, k=3, seed=args.seed)
    truth = data["ground_truth"]
    top = joint_errors(data["proposals"][:, :, 0], truth)
    rows = [["top-1 proposals (no fit)", "-", f"{top.mean():.2f}", f"{np.median(top.mean(1)):.2f}", "-",
             f"{success_rate(top, [40])[0]:.3f}"]]
    for name, budget, config in VARIANTS:
        r = hybridfit.fit(data["proposals"], data["confidences"], budget=budget, optimizer_config=config,
                          jobs=args.jobs, seed=args.seed)
        e = joint_errors(r.joints, truth)
        rows.append([name, budget, f"{e.mean():.2f}", f"{np.median(e.mean(1)):.2f}", f"{r.objective.mean():.3f}",
                     f"{success_rate(e, [40])[0]:.3f}"])
        print(f"done: {name}", file=sys.stderr, flush=True)
    print(f"## Stepwise vs joint optimisation ({args.frames} synthetic frames, k = 3)\n")
    print(table(["variant", "budget", "mean error (mm)", "median frame error (mm)", "objective -E (mean)",
                 "success @40 mm"], rows))


if __name__ == "__main__":
    main()
