"""Why an item is still where it was: its latest failure, with what that failure named.

A run that gives up names each item left with its reason (Verification._why_left). Every failure used to be
appended to the item's reasons and the message listed them all, sorted: an item that first waited for a bowl lying
on it ("pinned by the bowl lying on it") and, once the bowls were placed, failed otherwise (its lift ran into a
plate, too hidden to plan, no free slot) was still reported "pinned by the bowl", the bowl long placed. Now each
failure replaces the item's :class:`Reason`: its kind, the strategy whose plan failed last, and the items it named
lying on the item or in its way (whether they pin it). The message names the named items only while they are
still where they were named (perceived or put down there, within NAMED_TOL); one that has gone since (placed
elsewhere, moved) is dropped and the message says so. The item's full history of failure kinds stays in
``Attempts.reasons`` (a strategy reads it: a lift blocked a second time).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from kitchenbot.perception.types import ObjectPose

# m: a named item perceived this close to where it was named is still there. A re-estimate of an item that did not
# move is within a millimetre or two (executive/waiting.py); a plate nested under a named one lies a nest's pitch
# (about 7 mm) from it, and must not stand in for it once the named one is placed.
NAMED_TOL = 0.005


@dataclass(eq=False)
class Reason:
    """An item's latest failure: `kind` (a planner's failure kind, an executed attempt's failure kind, or the task's
    text such as "no_free_slot: ..."), `strategy` (the strategy whose plan failed last, planning failures only),
    `named` ((class, position) of each item the failure named lying on it or in its way) and whether those pin it
    (its lift fails at the grasp whatever the grasp: executive/waiting.py)."""

    kind: str
    strategy: str = ""
    named: list = field(default_factory=list)
    pinned: bool = False

    @classmethod
    def of(cls, kind: str, strategy: str = "", named: Sequence[ObjectPose] = (), pinned: bool = False) -> Reason:
        return cls(kind, strategy, [(p.cls, np.array(p.T_base_obj, float)[:3, 3].copy()) for p in named], pinned)

    def still_named(self, scene: Sequence[ObjectPose], itself: ObjectPose | None = None) -> list[str]:
        """The classes of the named items still in `scene` (the belief's scene_objects) where they were named (not
        `itself`: the item reported, which may lie within NAMED_TOL of an item nested on it)."""
        out = []
        for c, pos in self.named:
            if any(p is not itself and p.cls == c
                   and np.linalg.norm(np.asarray(p.T_base_obj, float)[:3, 3] - pos) <= NAMED_TOL for p in scene):
                out.append(c)
        return out

    def describe(self, scene: Sequence[ObjectPose], itself: ObjectPose | None = None) -> str:
        """E.g. "cartesian_path_failed in direct_pick; pinned by the bowl, bowl lying on it", "no_graspable_object
        in pick_hidden_blocker; in its way: the plate", "cartesian_path_failed in direct_pick; what it named (the
        bowl) has gone since"."""
        parts = [self.kind + (f" in {self.strategy}" if self.strategy else "")] if self.kind else []
        here = self.still_named(scene, itself)
        if here:
            what = "the " + ", ".join(here)
            parts.append(f"pinned by {what} lying on it" if self.pinned else f"in its way: {what}")
        elif self.named:
            parts.append(f"what it named (the {', '.join(c for c, _ in self.named)}) has gone since")
        return "; ".join(parts)
