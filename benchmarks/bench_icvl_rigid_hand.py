"""ICVL as a user fits it: the paper's proposals and LRF's predictions through ``hybridfit fit``,
self-calibrated, calibrated on the annotations of frames 0-99, and as configured.

    python benchmarks/bench_icvl_rigid_hand.py [--data ../shared/data/icvl] [--frames N]

Runs these commands (printed as they run) in a temporary folder and reads each mean joint
error from ``hybridfit evaluate`` (frames 100 onwards, the ones no calibration saw, and all
frames), the same means ``read_xyz`` gives. ``--frames N`` fits the first N frames only (a
smoke test: the calibration's frames 0-99 need N > 100). Writes
``benchmarks/results/icvl_rigid_hand.json`` (``--json``).
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _util import json_argument, table_record, write_record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data" / "icvl"))
    ap.add_argument("--frames", type=int, default=None, help="fit the first N frames only (a smoke test)")
    json_argument(ap, "icvl_rigid_hand")
    a = ap.parse_args()
    data = Path(a.data).resolve()
    truth = data / "icvl_test_groundtruth_label.txt"
    proposals, lrf_file = data / "poier2015_proposals.npz", data / "lrf_cvpr14_predictions.txt"
    figures: list[dict] = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if a.frames:  # the first N frames of each input
            with np.load(proposals) as d:
                np.savez(work / "poier.npz", **{k: d[k][:a.frames] if d[k].ndim and len(d[k]) > a.frames else d[k]
                                                for k in d.files})
            proposals = work / "poier.npz"
            lines = lrf_file.read_text().splitlines()[:a.frames]
            (work / "lrf.txt").write_text("\n".join(lines) + "\n")
            lrf_file = work / "lrf.txt"
            (work / "truth.txt").write_text("\n".join(truth.read_text().splitlines()[:a.frames]) + "\n")
            truth = work / "truth.txt"

        def run(*args: str) -> str:
            print("$ hybridfit " + shlex.join(args), flush=True)
            return subprocess.run([sys.executable, "-m", "hybridfit", *args], cwd=work, check=True, text=True,
                                  capture_output=True).stdout

        def error(file: Path | str, frames: str | None) -> float:
            out = run("evaluate", str(file), "--dataset", "icvl", "--ground-truth", str(truth),
                      *(("--frames", frames) if frames else ()))
            name = Path(file).name  # a proposals file has rows "NAME top-1" and "NAME optimized": the top-1
            rows = [line.split()[1:] for line in out.splitlines() if line.split() and line.split()[0] == name]
            row = next((r for r in rows if r[0] == "top-1"), rows[0])
            return float(row[1] if row[0] == "top-1" else row[0])

        def figure(name: str, file: Path | str) -> list[float]:
            later, every = error(file, "100:"), error(file, None)
            figures.append({"figure": name, "mm_frames_100_1595": later, "mm_all_frames": every})
            return [later, every]

        fit = ("fit", str(proposals), "--dataset", "icvl")
        run("calibrate", "--dataset", "icvl", "--ground-truth", str(truth), "--frames", "0:100", "--out", "icvl.toml")
        run("calibrate", "--dataset", "icvl", "--ground-truth", str(truth), "--frames", "0:100", "--model", "hand27",
            "--out", "icvl27.toml")
        run(*fit, "--out", "self.npz")
        run(*fit, "--model", "hand27", "--out", "self27.npz")
        run(*fit, "--model-config", "icvl.toml", "--out", "gt.npz")
        run(*fit, "--model-config", "icvl27.toml", "--out", "gt27.npz")
        run(*fit, "--calibrate", "none", "--out", "none.npz")
        run("proposals", "from-results", "--dataset", "icvl", str(lrf_file), "--out", "lrf.npz")
        run("fit", "lrf.npz", "--model", "hand27", "--out", "lrf27.npz")
        run("fit", "lrf.npz", "--model", "hand27", "--model-config", "icvl27.toml", "--out", "lrf27gt.npz")
        poier = {
            "top1": figure("the paper's top-1 proposals (no fit)", proposals),
            "self": figure("hand29, self-calibrated", work / "self.npz"),
            "self27": figure("hand27, self-calibrated", work / "self27.npz"),
            "gt": figure("hand29, calibrated on the annotations of frames 0-99", work / "gt.npz"),
            "gt27": figure("hand27, calibrated on the annotations of frames 0-99", work / "gt27.npz"),
            "none": figure("as configured (--calibrate none: hand26)", work / "none.npz"),
        }
        lrf = {
            "lrf": figure("LRF's predictions (published)", lrf_file),
            "self": figure("LRF's predictions fitted, hand27, self-calibrated", work / "lrf27.npz"),
            "gt": figure("LRF's predictions fitted, hand27 calibrated on frames 0-99", work / "lrf27gt.npz"),
        }

    def mm(pair, bold=False):
        text = f"{pair[0]:.2f} ({pair[1]:.2f})"
        return f"**{text}**" if bold else text

    tables = {
        "poier": table_record(["the paper's proposals (k = 3)", "hand29 (the default)", "hand27"], [
            ["self-calibrated from the proposals (no ground truth)", mm(poier["self"], True), mm(poier["self27"])],
            ["calibrated on the annotations of frames 0-99", mm(poier["gt"], True), mm(poier["gt27"])],
            ["as configured (`--calibrate none`: hand26)", mm(poier["none"]), ""],
            ["top-1 proposals, no fit", mm(poier["top1"]), ""]]),
        "lrf": table_record(["LRF's predictions (k = 1)", "hand27"], [
            ["LRF itself, no fit", mm(lrf["lrf"])], ["fitted, self-calibrated", mm(lrf["self"])],
            ["fitted, calibrated on the annotations of frames 0-99", mm(lrf["gt"])]]),
    }
    for name, t in tables.items():
        print(f"\n{name}: mean joint error, mm, frames 100-1595 (all frames)")
        for row in t["rows"]:
            print("  " + " | ".join(row))
    write_record(a.json, tables, figures=figures)


if __name__ == "__main__":
    main()
