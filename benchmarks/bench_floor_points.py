"""Where the floor lives: the annotations' residual after fit + polish, per point.

    python benchmarks/bench_floor_points.py [--real icvl] [--model hand27] [--subset 0:100]
                                            [--jobs 1] [--polish KEY=VALUE ...]

On the tuning data only (default: ICVL frames 0-99), ``hybridfit.fitting.calibrate`` with
its defaults calibrates the model on the subset (as ``bench_floor --subset 0:100 --pool
0:100`` does); every frame of the subset is then fitted (``hybridfit.fit``, the annotations
as k = 1 proposals) and polished (``refine`` with the default per-frame bone and palm freedom,
changed by the ``--polish`` options: ``palm_tolerance_mm=0`` for 0.7.0's rigid palm). Per annotated point, the residual (annotation - fitted point) is
expressed in two frames of the fitted hand:

- the palm's: y from the wrist to the middle MCP, x across the index and little MCPs
  (orthogonalised), z = x cross y (palmar for a right hand);
- the point's bone: y along the bone that ends at the point's joint (its parent to it), x
  the palm's x orthogonalised against it, z = x cross y (for a derived point, the palm's).

Printed per point: the mean 3D error over all frames and over calibration's held-out ones
(mm), and in each frame the share of the mean squared residual that is constant, |mean
residual|^2 / mean |residual|^2 (1: a constant offset the geometry could absorb; 0: it
changes from frame to frame), with the constant vector (mm). Then per group (palm point,
thumb, finger MCPs, PIPs, tips) the share of the total squared residual, and the
correlation of the finger MCPs' in-palm residual with the annotated MCP spread (index to
little MCP distance) and of the palm-normal residual with the annotated palm arch (the
ring and middle MCPs' height over the plane of the wrist, index and little MCPs).
"""

from __future__ import annotations

import argparse

import numpy as np

import hybridfit
from hybridfit.datasets.skeletons import dataset_model_config, skeleton
from hybridfit.fitting.calibrate import calibrate
from hybridfit.fitting.refine import BONE_TOLERANCE, BONE_WEIGHT, PALM_TOLERANCE_MM, PALM_WEIGHT, refine

from _util import table
from bench_floor import annotations


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def palm_frames(joints: np.ndarray, model) -> np.ndarray:
    """(F, 3, 3) rows x, y, z of the palm's frame of model joints (F, J, 3) mm."""
    n = {name: i for i, name in enumerate(model.joint_names)}
    y = _unit(joints[:, n["middle_mcp"]] - joints[:, n["wrist"]])
    x = joints[:, n["index_mcp"]] - joints[:, n["little_mcp"]]
    x = _unit(x - (x * y).sum(-1, keepdims=True) * y)
    return np.stack([x, y, np.cross(x, y)], axis=1)


def bone_frames(joints: np.ndarray, model, names) -> np.ndarray:
    """(F, Q, 3, 3) rows x, y, z of each named point's bone frame (the palm's for a derived point)."""
    palm = palm_frames(joints, model)
    index = {name: i for i, name in enumerate(model.joint_names)}
    parents = np.asarray(model.parents)
    out = np.repeat(palm[:, None], len(names), axis=1)
    for q, name in enumerate(names):
        j = index.get(name)
        if j is None or parents[j] < 0:
            continue
        y = _unit(joints[:, j] - joints[:, parents[j]])
        x = palm[:, 0] - (palm[:, 0] * y).sum(-1, keepdims=True) * y
        x = _unit(x)
        out[:, q] = np.stack([x, y, np.cross(x, y)], axis=1)
    return out


def constant_share(local: np.ndarray) -> tuple[float, np.ndarray]:
    """local (F, 3) residuals in a frame -> (|mean|^2 / mean |r|^2, mean (3,))."""
    mean = local.mean(0)
    return float((mean**2).sum() / (local**2).sum(-1).mean()), mean


def group(name: str) -> str:
    if name.startswith("thumb"):
        return "thumb"
    if name.endswith("_mcp"):
        return "finger MCPs"
    if name.endswith("_pip"):
        return "PIPs"
    if name.endswith("_tip"):
        return "finger tips"
    return "palm point"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--real", default="icvl")
    ap.add_argument("--model", default="hand27")
    ap.add_argument("--subset", default="0:100", help="the tuning frames START:STOP[:STEP]")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--polish", nargs="*", default=[], help="refine options KEY=VALUE (floats)")
    a = ap.parse_args()
    names = skeleton(a.real).model_names
    truth = annotations("real", a.real)[slice(*(int(v) if v else None for v in a.subset.split(":")))]
    cal = calibrate(truth, names, model=a.model, model_config=dataset_model_config(a.model, {}, a.real), jobs=a.jobs)
    model = hybridfit.create("model", a.model, cal.settings)
    ones = np.ones(truth.shape[:2] + (1,))
    fitted = hybridfit.fit(truth[:, :, None], ones, joint_names=names, model=a.model, model_config=cal.settings,
                           jobs=a.jobs)
    options = {"bone_tolerance": BONE_TOLERANCE, "bone_weight": BONE_WEIGHT, "palm_tolerance_mm": PALM_TOLERANCE_MM,
               "palm_weight": PALM_WEIGHT, **{k: float(v) for k, v in (o.split("=") for o in a.polish)}}
    polished = refine(model, fitted.params, truth[:, :, None], ones, names, **options)
    joints, points = polished.joints(model), polished.points(model, names)
    residual = truth - points  # (F, Q, 3)
    err = np.linalg.norm(residual, axis=-1)
    held = cal.heldout_frames
    palm = np.einsum("fij,fqj->fqi", palm_frames(joints, model), residual)
    bone = np.einsum("fqij,fqj->fqi", bone_frames(joints, model, names), residual)
    rows = []
    for q, name in enumerate(skeleton(a.real).names):
        share_p, mean_p = constant_share(palm[:, q])
        share_b, mean_b = constant_share(bone[:, q])
        rows.append([name, f"{err[:, q].mean():.2f}", f"{err[held, q].mean():.2f}",
                     f"{(err[:, q] ** 2).sum() / (err ** 2).sum():.1%}",
                     f"{share_p:.2f} ({', '.join(f'{v:+.1f}' for v in mean_p)})",
                     f"{share_b:.2f} ({', '.join(f'{v:+.1f}' for v in mean_b)})"])
    print(f"{a.real} {a.subset}, {a.model}, polish {options}: floor {err.mean():.2f} mm on all "
          f"{len(truth)} frames, {err[held].mean():.2f} on the {len(held)} held out")
    print(table(["point", "mean error (mm)", "held out", "share of squared residual",
                 "constant share, palm frame (mean x, y, z mm)", "constant share, bone frame (mean x, y, z mm)"],
                rows))
    groups = {}
    for q, name in enumerate(names):
        groups.setdefault(group(name), []).append(q)
    total = (err**2).sum()
    print(table(["group", "share of squared residual", "mean error (mm)"],
                [[g, f"{(err[:, qs] ** 2).sum() / total:.1%}", f"{err[:, qs].mean():.2f}"]
                 for g, qs in groups.items()]))
    # per-frame palm shape: MCP spread and palm arch against the MCPs' residuals
    q = {name: i for i, name in enumerate(names)}
    mcps = [q[f"{f}_mcp"] for f in ("index", "middle", "ring", "little")]
    spread = np.linalg.norm(truth[:, q["index_mcp"]] - truth[:, q["little_mcp"]], axis=-1)
    fitted_spread = np.linalg.norm(points[:, q["index_mcp"]] - points[:, q["little_mcp"]], axis=-1)
    across = palm[:, q["index_mcp"], 0] - palm[:, q["little_mcp"], 0]  # the residual's spread along x
    normal = palm_frames(joints, model)[:, 2]
    plane = truth[:, [q["index_mcp"], q["little_mcp"]]].mean(1)
    arch = ((truth[:, [q["middle_mcp"], q["ring_mcp"]]].mean(1) - plane) * normal).sum(-1)
    fitted_arch = ((points[:, [q["middle_mcp"], q["ring_mcp"]]].mean(1)
                    - points[:, [q["index_mcp"], q["little_mcp"]]].mean(1)) * normal).sum(-1)
    print(f"MCP spread (index-little, mm): annotated {spread.mean():.1f} +- {spread.std():.1f}, fitted "
          f"{fitted_spread.mean():.1f} +- {fitted_spread.std():.1f}; corr(annotated spread, residual spread along x) "
          f"{np.corrcoef(spread, across)[0, 1]:+.2f}")
    print(f"palm arch (middle/ring MCPs over index/little, along the palm normal, mm): annotated "
          f"{arch.mean():+.1f} +- {arch.std():.1f}, fitted {fitted_arch.mean():+.1f} +- {fitted_arch.std():.1f}; "
          f"corr(annotated, fitted) {np.corrcoef(arch, fitted_arch)[0, 1]:+.2f}")
    tolerance = options.get("palm_tolerance_mm", 0.0)
    if tolerance > 0:  # the polish's palm freedom: how far the bases moved, how often to the tolerance
        bases = np.flatnonzero(np.isin(np.asarray(model.parents), np.flatnonzero(np.asarray(model.parents) < 0)))
        moves = polished.base_moves[:, bases]
        print("base moves (hand frame, mm): " + "; ".join(
            f"{model.joint_names[b]} mean |move| {np.linalg.norm(moves[:, i], axis=-1).mean():.1f}, "
            f"sd x/y/z {' / '.join(f'{v:.1f}' for v in moves[:, i].std(0))}" for i, b in enumerate(bases))
            + f"; coordinates at the tolerance {(np.abs(moves) >= tolerance - 1e-9).mean():.1%}")
    mcp_err = err[:, mcps].mean(1)
    print(f"finger MCPs' mean error per frame {mcp_err.mean():.2f} +- {mcp_err.std():.2f} mm; "
          f"corr with |arch - mean| {np.corrcoef(np.abs(arch - arch.mean()), mcp_err)[0, 1]:+.2f}, "
          f"with |spread - mean| {np.corrcoef(np.abs(spread - spread.mean()), mcp_err)[0, 1]:+.2f}")


if __name__ == "__main__":
    main()
