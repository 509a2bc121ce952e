"""Planning settings (the `planning:` section of the cell config)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class PlanningSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")

    planner_timeout: float = Field(1.0, gt=0.0, le=60.0, description="seconds per RRT-Connect query")
    simplify_timeout: float = Field(0.2, ge=0.0, le=10.0)
    validity_resolution: float = Field(0.004, gt=0.0, le=0.05, description="max TCP travel (m) between checked states")
    approach_distance: float = Field(0.10, gt=0.0, le=0.3, description="straight approach/retreat, metres")
    lift_height: float = Field(0.15, gt=0.0, le=0.5)
    max_occlusion: float = Field(0.6, ge=0.0, le=1.0, description="skip objects hidden more than this fraction")
    velocity_scale: float = Field(0.5, gt=0.0, le=1.0)
    acceleration_scale: float = Field(0.5, gt=0.0, le=1.0)
