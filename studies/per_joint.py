"""Print a study's per-joint mean errors (mm) as a Markdown table, one column per variant.

    python studies/per_joint.py study_out/models

The joint names are the trials' point names (a dataset skeleton's model points); values are
the mean over frames and seeds, as in the study's per-joint plot (``hybridfit.study.report``).
"""

from __future__ import annotations

import sys
from pathlib import Path

from hybridfit.study.report import aggregate
from hybridfit.study.runner import DB_NAME
from hybridfit.study.store import Store


def per_joint_table(out: Path) -> str:
    store = Store(Path(out) / DB_NAME)
    try:
        rows = aggregate(store)
    finally:
        store.close()
    names = list(rows[0]["joint_names"])
    lines = ["| joint | " + " | ".join(r["variant"].replace("|", "\\|") for r in rows) + " |", "|---" * (len(rows) + 1) + "|"]
    for j, name in enumerate(names):
        lines.append(f"| {name} | " + " | ".join(f"{r['per_joint'][j]:.2f}" for r in rows) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(per_joint_table(Path(sys.argv[1])))
