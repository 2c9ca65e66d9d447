"""``hybridfit export``: a fits file (.npz) as JSON, BVH, glTF or CSV, the format taken from
``--out``'s extension (:mod:`hybridfit.exports`)."""

from __future__ import annotations

from ..exports import export, export_format
from ..exports.bvh import MAX_FPS, MIN_FPS
from ._common import _number, declare_paths


def bvh_fps(text: str) -> float:
    """--fps: a frame rate whose Frame Time a BVH holds."""
    return _number(text, float, lambda v: MIN_FPS <= v <= MAX_FPS, f"a frame rate from {MIN_FPS:g} to {MAX_FPS:g}")


def register(sub) -> None:
    p = sub.add_parser("export", help="write fits as JSON, BVH, glTF or CSV (the format from --out's extension)")
    p.add_argument("fits", help="npz from `hybridfit fit` or `estimate`; for all but .csv, one that names "
                   "its model (an older hybridfit's file: re-run `hybridfit fit`)")
    p.add_argument("--out", required=True, help="FILE.json: per frame the named joints (mm) and angles (degrees), "
                   "with the model and its settings; FILE.bvh: the model's skeleton and every frame's rotations "
                   "(mm, camera coordinates; failed frames hold the previous pose); FILE.glb or FILE.gltf: "
                   "the model's surface skinned to its skeleton, a keyframe per frame (metres, y up; failed "
                   "frames hold the previous pose); FILE.csv: the angle table of `hybridfit export-angles`")
    p.add_argument("--fps", type=bvh_fps, default=30.0, help=f"frame rate of a .bvh, .json, .glb or .gltf, from "
                   f"{MIN_FPS:g} to {MAX_FPS:g} (a BVH's Frame Time is 1/fps; default 30)")
    p.add_argument("--model", help="for .csv only: the model that made a fits file without parameter_names "
                   "(hybridfit 0.3.0 and older), e.g. hand26")
    declare_paths(p, inputs=("fits",), outputs=("--out",))
    p.set_defaults(func=run)


def run(args) -> int:
    export_format(args.out)  # an unknown extension: refused before anything is read
    done = export(args.fits, args.out, model=args.model, fps=args.fps)
    failed = ""
    if done.failed:
        shown = ", ".join(str(f) for f in done.failed[:10]) + (f" and {len(done.failed) - 10} more"
                                                                 if len(done.failed) > 10 else "")
        held = "; they hold the previous pose" if done.format in ("BVH", "GLB", "glTF") else ", marked"
        failed = f" ({len(done.failed)} failed: {shown}{held})"
    print(f"wrote {done.frames} frames{failed} as {done.format} -> {args.out}")
    return 0
