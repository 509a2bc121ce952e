"""Per-view detection and segmentation interfaces.

A ``Detector`` gives boxes per view (an open-vocabulary detector prompted with "dishware", or the geometric
default); a ``Segmenter`` turns boxes into instance masks (SAM2 prompted by the boxes, or the geometric
default which already has masks). Everything downstream (association, map, poses) sees only ``Detection``s,
so learned backends plug in without touching the rest.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from kitchenbot.perception.types import View


@dataclass
class Detection:
    """One object seen in one view: box (x0, y0, x1, y1 pixels, inclusive-exclusive), mask (H, W) bool."""

    box: np.ndarray
    score: float
    mask: np.ndarray | None = None
    label: str = "dishware"

    @property
    def area(self) -> int:
        return int(self.mask.sum()) if self.mask is not None else 0


def box_of(mask: np.ndarray) -> np.ndarray:
    rows, cols = np.nonzero(mask)
    if len(rows) == 0:
        return np.zeros(4)
    return np.array([cols.min(), rows.min(), cols.max() + 1, rows.max() + 1], float)


@runtime_checkable
class Detector(Protocol):
    def detect(self, view: View) -> list[Detection]:
        """Boxes (masks optional) of the objects in one view."""
        ...


@runtime_checkable
class Segmenter(Protocol):
    def segment(self, view: View, detections: list[Detection]) -> list[Detection]:
        """The same detections with a mask each (detections without a usable mask are dropped)."""
        ...


class PassThroughSegmenter:
    """For detectors that already give masks (the geometric one): keeps detections that have a mask."""

    def segment(self, view: View, detections: list[Detection]) -> list[Detection]:
        return [d for d in detections if d.mask is not None and d.mask.any()]
