"""Skeleton mappings: each dataset's annotated points, and the model point each maps onto.

A dataset point is either a hand26 joint or a named derived point (a fixed weighted sum of
joints; see ``DERIVED``). Fitting and evaluation use exactly these points. Derived points'
default weights are guesses from the datasets' annotation conventions; ``hybridfit
calibrate`` fits them to annotated frames and writes them into the model config.

| dataset | points | mapped onto hand26 |
| --- | --- | --- |
| icvl (16) | palm; per finger (thumb, index, middle, ring, little) root, mid, tip | palm -> ``icvl_palm`` (derived); thumb root, mid, tip -> thumb_mcp, thumb_ip, thumb_tip; finger root, mid, tip -> mcp, pip, tip |
| nyu (14 of 36) | per finger (little, ring, middle, index) tip (KNU3_A) and mid (KNU2_B); thumb tip (KNU3_A), mid (KNU3_B), root (KNU2_B); PALM_1, PALM_2, PALM_3 | tip -> tip, mid -> pip; thumb -> tip, ip, mcp; PALM_1/2 -> ``nyu_wrist_1``/``nyu_wrist_2`` (derived, the two sides of the wrist), PALM_3 -> ``nyu_palm`` (derived) |
| msra (21) | wrist; per finger (index, middle, ring, little, thumb) mcp, pip, dip, tip | wrist -> wrist; fingers one to one; thumb mcp, pip, dip, tip -> thumb_cmc, thumb_mcp, thumb_ip, thumb_tip |
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import HybridfitError

_PALM5 = ("wrist", "index_mcp", "middle_mcp", "ring_mcp", "little_mcp")

#: default weights of the dataset-specific derived points (hand26 joints)
DERIVED: dict[str, dict[str, float]] = {
    # ICVL's palm point lies between the wrist and the palm centre
    "icvl_palm": {"wrist": 0.4, **{j: 0.15 for j in _PALM5[1:]}},
    "nyu_palm": {j: 0.2 for j in _PALM5},
    # the two wrist points: the wrist moved towards the little and the index side
    "nyu_wrist_1": {"wrist": 1.0, "little_mcp": 0.4, "index_mcp": -0.4},
    "nyu_wrist_2": {"wrist": 1.0, "little_mcp": -0.4, "index_mcp": 0.4},
}
#: joints whose weights calibration may change for each derived point (its support)
SUPPORT = ("wrist", "thumb_cmc", "index_mcp", "middle_mcp", "ring_mcp", "little_mcp")


@dataclass(frozen=True)
class Skeleton:
    """A dataset's points: ``names`` (J,) its own names in file order, ``model_names`` (J,)
    the model point each maps onto, ``fingertips`` indices of the fingertips."""

    dataset: str
    names: tuple[str, ...]
    model_names: tuple[str, ...]
    fingertips: tuple[int, ...]

    @property
    def derived(self) -> dict[str, dict[str, float]]:
        """The derived points this skeleton needs, with their default weights."""
        return {n: dict(DERIVED[n]) for n in self.model_names if n in DERIVED}

    def __len__(self) -> int:
        return len(self.names)


def _icvl() -> Skeleton:
    names, model = ["palm"], ["icvl_palm"]
    for f in ("thumb", "index", "middle", "ring", "little"):
        names += [f"{f}_root", f"{f}_mid", f"{f}_tip"]
        model += ["thumb_mcp", "thumb_ip", "thumb_tip"] if f == "thumb" else [f"{f}_mcp", f"{f}_pip", f"{f}_tip"]
    return Skeleton("icvl", tuple(names), tuple(model), (3, 6, 9, 12, 15))


#: NYU's 36 annotated points (joint_data.mat order): 6 per finger F1 (little) .. F4 (index), thumb, palm
NYU36 = tuple(
    f"{f}_{k}" for f in ("F1", "F2", "F3", "F4", "TH")
    for k in ("KNU3_A", "KNU3_B", "KNU2_A", "KNU2_B", "KNU1_A", "KNU1_B")
) + tuple(f"PALM_{i}" for i in range(1, 7))
#: the common 14-point evaluation subset (Tompson et al. 2014), indices into NYU36
NYU14 = (0, 3, 6, 9, 12, 15, 18, 21, 24, 25, 27, 30, 31, 32)


def _nyu() -> Skeleton:
    model = []
    for f in ("little", "ring", "middle", "index"):
        model += [f"{f}_tip", f"{f}_pip"]
    model += ["thumb_tip", "thumb_ip", "thumb_mcp", "nyu_wrist_1", "nyu_wrist_2", "nyu_palm"]
    return Skeleton("nyu", tuple(NYU36[i] for i in NYU14), tuple(model), (0, 2, 4, 6, 8))


def _msra() -> Skeleton:
    names, model = ["wrist"], ["wrist"]
    for f in ("index", "middle", "ring", "little", "thumb"):
        names += [f"{f}_{j}" for j in ("mcp", "pip", "dip", "tip")]
        model += ["thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip"] if f == "thumb" else \
            [f"{f}_mcp", f"{f}_pip", f"{f}_dip", f"{f}_tip"]
    return Skeleton("msra", tuple(names), tuple(model), (4, 8, 12, 16, 20))


SKELETONS: dict[str, Skeleton] = {s.dataset: s for s in (_icvl(), _nyu(), _msra())}


def skeleton(dataset: str) -> Skeleton:
    """The skeleton of a dataset by name (icvl, nyu, msra)."""
    try:
        return SKELETONS[dataset.lower()]
    except KeyError:
        raise HybridfitError(f"unknown dataset {dataset!r} (known: {', '.join(SKELETONS)})") from None


def with_derived_points(model_config: dict, dataset: str) -> dict:
    """hand26 settings with the skeleton's derived points added where the config lacks them."""
    derived = dict(model_config.get("derived_points", {}))
    for name, weights in skeleton(dataset).derived.items():
        derived.setdefault(name, weights)
    return {**model_config, "derived_points": derived}


def dataset_model_config(model: str, model_config: dict, dataset: str | None) -> dict:
    """The fitting model's settings for a dataset's skeleton: hand26 gets the skeleton's
    derived points (it has a setting for them); other models and no dataset: unchanged."""
    if model != "hand26" or not dataset:
        return dict(model_config)
    return with_derived_points(model_config, dataset)
