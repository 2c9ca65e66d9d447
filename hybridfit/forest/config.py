"""Forest training settings (``ForestConfig``), stored in every forest file."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class ForestConfig(BaseModel):
    """Forest training settings. Defaults follow the paper where it gives a value."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    n_trees: int = Field(3, ge=1, description="trees in the forest (paper: 3)")
    max_depth: int = Field(23, ge=1, le=40, description="maximum tree depth (paper: 23)")
    min_samples: int = Field(40, ge=2, description="a node with fewer samples becomes a leaf (paper: 40)")
    pixels_per_frame: int = Field(
        400, ge=1,
        description="foreground pixels sampled per training frame (the paper gives no value; 400 rather than 200, "
                    "chosen by measurement: the docs' results page, section \"Forest training pixels\")")
    node_subsample: int = Field(1000, ge=10, description="class-balanced sub-sample size for split selection")
    n_features: int = Field(100, ge=1, description="candidate features per node")
    n_thresholds: int = Field(20, ge=1, description="candidate thresholds per feature (drawn from the sub-sample)")
    max_feature_offset_mm: float = Field(60.0, gt=0, description="feature offsets u, v drawn in [-r, r]^2 mm")
    p_unary: float = Field(0.5, ge=0, le=1, description="share of features with v = 0 (compare to the pixel itself)")
    criterion: Literal["entropy", "gini"] = Field("entropy", description="impurity of part labels for the gain")
    leaf_modes: int = Field(2, ge=1, description="offset modes kept per joint and leaf")
    leaf_bandwidth_mm: float = Field(10.0, gt=0, description="mean-shift bandwidth on leaf offsets, mm")
    max_offset_mm: float = Field(100.0, gt=0, description="offsets longer than this are discarded at the leaves, mm")
    leaf_max_samples: int = Field(200, ge=1, description="at most this many samples per leaf go into mean-shift")
    background_mm: float = Field(10000.0, gt=0, description="depth read at background and outside the image, mm")
    seed: int = Field(0, description="random seed; same seed and data give the same forest bit for bit")
