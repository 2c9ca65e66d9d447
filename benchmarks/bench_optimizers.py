"""Every registered optimiser, stepwise and joint, at equal budgets on the same frames.

Synthetic proposal frames (``hybridfit.synthetic_proposals``: k = 3, noise and decoys) are
fitted with the reference model and objective by each registered optimiser (default
settings) run through the ``stepwise`` wrapper with ``schedule`` stepwise and joint, at
budgets of 1000, 3400 and 8300 evaluations per frame. Printed as a Markdown table of
medians over frames (the machine is shared and noisy): mean joint error against the
ground truth (mm), objective value reached (lower is better) and time per frame (ms).
A configuration whose budget is below the optimiser's minimum is shown as such.

    python benchmarks/bench_optimizers.py --frames 6
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import hybridfit
from hybridfit import registry
from hybridfit.errors import HybridfitError

BUDGETS = (1000, 3400, 8300)
WRAPPERS = ("stepwise", "stepwise-pso")  # wrappers themselves: their inner optimisers are benchmarked instead


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=4, help="synthetic frames (default 4)")
    parser.add_argument("--budgets", type=int, nargs="+", default=list(BUDGETS), help="evaluations per frame")
    parser.add_argument("--optimizers", nargs="+", default=None, help="registered names (default: all)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    data = hybridfit.synthetic_proposals(args.frames, k=3, noise_mm=5.0, seed=args.seed)
    names = args.optimizers or [n for n in registry.names("optimizer") if n not in WRAPPERS]
    print(f"{args.frames} synthetic frames (k = 3, noise 5 mm, decoys), hand26, clamped-confidence; medians\n")
    print("| optimizer | schedule | budget | joint error (mm) | objective | ms / frame | failed |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for name in names:
        for schedule in ("stepwise", "joint"):
            for budget in args.budgets:
                config = {"optimizer": name, "schedule": schedule}
                errors, objectives, ms, failed = [], [], [], 0
                try:
                    for f in range(args.frames):  # one frame at a time, to time each
                        start = time.perf_counter()
                        fit = hybridfit.fit(data["proposals"][f : f + 1], data["confidences"][f : f + 1],
                                            budget=budget, seed=args.seed + f, optimizer="stepwise",
                                            optimizer_config=config)
                        ms.append((time.perf_counter() - start) * 1000)
                        if fit.failed[0]:
                            failed += 1
                            continue
                        errors.append(np.linalg.norm(fit.joints[0] - data["ground_truth"][f], axis=-1).mean())
                        objectives.append(fit.objective[0])
                except HybridfitError as err:  # e.g. a budget below the optimiser's minimum
                    print(f"| {name} | {schedule} | {budget} | n/a | n/a | n/a | {err} |", flush=True)
                    continue
                print(f"| {name} | {schedule} | {budget} | {np.median(errors):.2f} | {np.median(objectives):.3f} | "
                      f"{np.median(ms):.0f} | {failed} |", flush=True)


if __name__ == "__main__":
    main()
