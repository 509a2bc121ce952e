"""Items that wait for what lies on them, and the order the candidates are tried in (blocker-first chains).

An item whose pick failed because it is pinned by items lying on it (``Planner._pinned_by``: at its grasp the item
is within the margin of such an item, so every lift of every grasp fails at its first state) gets the same answer
while it and those items lie as the belief has them: its pose and theirs alone decide it. Planned again after every
placement, a plate under a plate under a plate was planned, failed, and named the next one down, round after round.
Now it waits (a :class:`Wait` in the belief) and is not planned again until one of the items on it moves or goes
(its believed pose or presence changes), it moves itself, or marks appear around it (a contact mark, a keep-out).
A map perceived anew does not end a wait by itself: the verdict depends on the poses alone, and a re-scan that
finds the item and those on it where they were (within POSE_TOL, ROT_TOL) gives the same one (a full re-scan has
several times the points of the views before it, so "more points around it" held after every re-scan). Where it
would have been tried, the deepest item of its chain is tried instead: what lies on what lies on it, down to one
that does not wait (:class:`Chains`). A waiting item stays in the sink's reckoning: it is one of the task's items
left, and a run that ends with it names it with its reasons ("pinned by ...").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from kitchenbot.perception.types import ObjectPose
from kitchenbot.transforms import pose_error

POSE_TOL = 1e-3  # m: a belief pose this close (and within ROT_TOL) is the one the plan failed with
ROT_TOL = np.radians(0.5)  # rad; a re-estimate further off is planned anew
AROUND = 0.2  # m (horizontally) around the item: more marks there than when it failed means a new plan


def _same(cls: str, T: np.ndarray, p: ObjectPose) -> bool:
    """Whether `p` is the belief pose (class, pose) `cls`, `T`: within POSE_TOL and ROT_TOL."""
    if p.cls != cls:
        return False
    rot, pos = pose_error(np.asarray(p.T_base_obj, float), T)
    return pos <= POSE_TOL and rot <= ROT_TOL


def _around(points, T: np.ndarray) -> int:
    """Points (marks) within AROUND (horizontally) of the pose T."""
    if points is None or not len(points):
        return 0
    P = np.asarray(points, float).reshape(-1, 3)
    return int(np.count_nonzero(np.sum((P[:, :2] - T[:2, 3]) ** 2, axis=1) <= AROUND ** 2))


@dataclass(eq=False)
class Wait:
    """An item (its class and pose when its pick failed) pinned by `on_it` ((class, pose) of each item lying on it),
    with `around` marks (contact marks, keep-out: the belief's `marks`, not the perceived map) near it then."""

    cls: str
    T: np.ndarray
    on_it: list
    around: int


@dataclass
class Waits:
    records: list[Wait] = field(default_factory=list)

    def record(self, obj: ObjectPose, on_it: list[ObjectPose], marks) -> None:
        T = np.array(obj.T_base_obj, float)
        self.records = [w for w in self.records if not _same(w.cls, w.T, obj)]
        self.records.append(Wait(obj.cls, T, [(p.cls, np.array(p.T_base_obj, float)) for p in on_it],
                                 _around(marks, T)))

    def on(self, obj: ObjectPose, scene: list[ObjectPose], marks) -> list[ObjectPose] | None:
        """The scene's items that `obj` waits for (it is pinned by them), or None: it does not wait (any more: one
        of them moved or went, or marks around it were added (`marks`: the belief's contact marks and keep-out);
        the record is forgotten)."""
        w = next((w for w in self.records if _same(w.cls, w.T, obj)), None)
        if w is None:
            return None
        found = [next((p for p in scene if p is not obj and _same(c, T, p)), None) for c, T in w.on_it]
        if any(p is None for p in found) or _around(marks, w.T) > w.around:
            self.records = [r for r in self.records if r is not w]  # by identity: == compares arrays
            return None
        return found

    def reason(self, obj: ObjectPose) -> str:
        w = next((w for w in self.records if _same(w.cls, w.T, obj)), None)
        return "" if w is None else "pinned by the " + ", ".join(c for c, _ in w.on_it) + " lying on it"


@dataclass
class Chains:
    """One selection's view of the waits: `usable(p)` says whether `p` may be tried now (a candidate, or an item in
    the sink the task would move out of the way)."""

    waits: Waits
    scene: list[ObjectPose]
    marks: object  # the belief's marks (contact marks, keep-out), not the perceived map: see Waits.on
    usable: Callable[[ObjectPose], bool]

    def deepest(self, obj: ObjectPose, seen: tuple = ()) -> ObjectPose | None:
        """`obj` when it does not wait and may be tried; else, depth first, the deepest item of its chain that
        may be (None: none may; it stays where it is)."""
        if any(obj is s for s in seen):
            return None  # a cycle: each one waits for the other
        on = self.waits.on(obj, self.scene, self.marks)
        if on is None:
            return obj if self.usable(obj) else None
        for p in on:
            d = self.deepest(p, (*seen, obj))
            if d is not None:
                return d
        return None

    def order(self, cands: list[ObjectPose], prefer: ObjectPose | None) -> tuple[list[ObjectPose], list[ObjectPose]]:
        """(the candidates in order, each that waits replaced by the deepest item of its chain, `prefer` (the item
        named last as blocking another) first; those tried for another item's sake)."""
        out: list[ObjectPose] = []
        for_others: list[ObjectPose] = []
        for k, p in enumerate(([prefer] if prefer is not None else []) + list(cands)):
            d = self.deepest(p)
            if d is None or any(d is q for q in out):
                continue
            out.append(d)
            if k == 0 and prefer is not None or d is not p:
                for_others.append(d)
        return out, for_others
