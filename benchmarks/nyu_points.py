"""What NYU's 14 evaluation points are, read off the annotations themselves.

    python benchmarks/nyu_points.py [--labels ../shared/data/nyu/nyu_actor2_groundtruth_label.txt]

NYU's annotations come from fitting a hand model of spheres (Tompson et al. 2014), so two
points on one rigid bone keep their distance in every frame, and two points with a joint
between them do not, unless one lies on the joint's axis. Prints, for pairs of the 14
points, the distance's mean, standard deviation, minimum and maximum over the frames (mm).
Read with the skeleton files' comments (``hybridfit/datasets/skeleton_files/nyu.toml``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from hybridfit.datasets.results import read_xyz
from hybridfit.datasets.skeletons import skeleton

from _util import table

LABELS = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "nyu" / "nyu_actor2_groundtruth_label.txt"
PAIRS = (
    ("TH_KNU3_A", "TH_KNU3_B"), ("TH_KNU3_B", "TH_KNU2_B"), ("TH_KNU3_A", "TH_KNU2_B"),
    *((f"F{i}_KNU3_A", f"F{i}_KNU2_B") for i in (4, 3, 2, 1)),
    ("PALM_1", "PALM_2"), ("PALM_1", "PALM_3"), ("PALM_2", "PALM_3"),
    ("F4_KNU2_B", "PALM_1"), ("F4_KNU2_B", "PALM_2"), ("F1_KNU2_B", "PALM_1"), ("F1_KNU2_B", "PALM_2"),
    ("TH_KNU2_B", "PALM_1"), ("TH_KNU2_B", "PALM_2"),
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--labels", default=str(LABELS))
    a = ap.parse_args()
    x = read_xyz(a.labels, "nyu")
    names = list(skeleton("nyu").names)
    rows = []
    for p, q in PAIRS:
        d = np.linalg.norm(x[:, names.index(p)] - x[:, names.index(q)], axis=-1)
        rows.append([f"{p} - {q}", f"{d.mean():.1f}", f"{d.std():.2f}", f"{d.min():.1f}", f"{d.max():.1f}"])
    print(f"{len(x)} frames of {a.labels}\n")
    print(table(["points", "mean (mm)", "sd (mm)", "min (mm)", "max (mm)"], rows))


if __name__ == "__main__":
    main()
