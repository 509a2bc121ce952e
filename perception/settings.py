"""Perception settings (the `perception:` section of the cell config). Defaults follow the paper's
sensitivity analysis: 10 mm voxels, top-K = 3 candidates, IoU 0.6 for cross-view association."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class PerceptionSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")

    detector: Literal["geometric", "llmdet", "grounding-dino"] = "geometric"
    segmenter: Literal["geometric", "sam2"] = "geometric"
    image_encoder: Literal["none", "colour", "dinov2", "beit", "clip"] = "colour"
    point_encoder: str = Field("fpfh", description="'fpfh' or the name of a registered plug-in")
    fusion: bool = Field(True, description="fuse image patch features into the registration features (paper Alg. 1); "
                         "False: image class tokens for the candidate proposal only")
    prompt: str = "dishware"
    weights_dir: str = Field("~/.cache/kitchenbot/weights", description="local folder with model weights")
    voxel_size: float = Field(0.010, gt=0.0005, le=0.05, description="metres")
    top_k: int = Field(3, ge=1, le=20)
    candidate_threshold: float = Field(0.3, ge=-1.0, le=1.0)
    iou_threshold: float = Field(0.6, gt=0.0, lt=1.0)
    min_overlap: float = Field(0.5, ge=0.0, le=1.0, description="reject poses whose mean overlap ratio is lower")
    align_views: bool = Field(True, description="register the views onto the first one (ICP, coarse FPFH if needed)")
    use_cell: Literal["auto", "always", "never"] = Field(
        "auto", description="the cell description: auto = use it where it fits what the cameras see (else find "
        "supports and walls in the scan, with a warning); always; never (surfaces from the data only)")
    align_to_cell: bool = Field(True, description="register the scan onto the known cell geometry (sink floor, walls)")
    cache_dir: str = Field("~/.cache/kitchenbot/cad", description="where the CAD feature database is cached")
    residual_tolerance: float = Field(0.8, gt=0, le=3, description="voxels: query points farther than this from a found pose are re-fitted as another object (a nested item's peeking rim)")
    verify_threshold: float = Field(0.85, ge=0.0, le=1.0, description="reject poses whose verification (share of the judged model surface the depth does not see through, capped by the normals' agreement and by the share of the segment on the model at the sensor's precision; perception/verify.py) is lower; calibrated on generated scenes with distractors (dev seeds)")
    max_splits: int = Field(20, ge=0, le=50, description="times an instance may be split by re-fitting what a pose leaves unexplained")
