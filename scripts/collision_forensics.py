#!/usr/bin/env python3
"""Run one simulated task scene and report every collision the fake arm stopped on: which planned motion
(approach, grasp_in, lift, transfer, lower, retreat, or a joint move such as a scan waypoint), which bodies
("pad hits obj:UID"), the item being handled, and for every item in the cell its true pose against the closest
believed pose of its class (perceived, or a record of what the robot put down: `prov`; position error, rotation
error, visible fraction, verification, own points; "perceived": false where the belief has none within 10 cm: an
item nothing in the belief stands for). `log`: the runner's notes and results in order (what it selected,
planned, recovered, where it looked for a dropped item and what it found), the collisions among them.
`hidden` (per item hit): how it stood in what the planner checked at the stop: the share of its true surface the
map holds a point near, its map points the scene leaves unexplained and which belief items explain the rest
(`explained_by`, `in_instances`), and the share of its surface near neither an obstacle voxel nor a model
(`surface_in_neither`: real geometry the planner did not see). `--dump PREFIX` pickles what the planner knew at
each collision (belief objects, map, grasp, trajectory, simulator poses) to PREFIX_k.pkl for replay.

    KITCHENBOT_PLANNER_MAX_ITERATIONS=200 KITCHENBOT_PLANNER_SEED=0 \\
        python scripts/collision_forensics.py sink-to-dishwasher 800 > f.json
        python scripts/collision_forensics.py sink-to-dishwasher 800 --objects 20 --oracle-perception > f.json

Options as `kitchenbot bench tasks`: --slip, --objects, --oracle-perception.

Protective stops that are not collisions (a push of an item something rests on, a drag that jams on what the
item rests on, fingers pressed too deep, a limit) are described the same way in `stops` (as the motion started;
`--dump` writes PREFIX_stopK.pkl) and logged as PROTECTIVE_STOP.

Prints one JSON object: task, seed, delivered / wanted (truth), collisions, events, protective_stops, stops, log.
"""

from __future__ import annotations

import argparse
import json
import re

import numpy as np

from kitchenbot.executive.config import DriversConfig, load_config
from kitchenbot.executive.runner import run_task
from kitchenbot.transforms import rotation_angle


def main(task: str, seed: int, slip: float = 0.05, objects: int | None = None, oracle: bool = False,
         dump: str | None = None) -> dict:
    cfg = load_config(None).model_copy(update={"drivers": DriversConfig()})
    cfg.sim.slip_probability = slip
    if objects is not None:  # as `kitchenbot bench tasks --objects`
        cfg.sim.min_objects = cfg.sim.max_objects = objects
    events: list[dict] = []
    stops: list[dict] = []  # protective stops that were not collisions (a limit, a drag that jams, a loaded push)
    log: list[str] = []  # the runner's notes and results (not its device commands), in order
    moving = {"name": None}

    def hook(runner) -> None:
        arm, cls = runner.robot.arm, type(runner)
        run_traj, move_joints, event, note = cls._run_trajectory, cls._move_joints, arm._event, cls._log

        def _run_trajectory(self, traj, *args, **kwargs):
            moving["name"] = getattr(traj, "name", "?")
            moving["traj"] = traj
            return run_traj(self, traj, *args, **kwargs)

        def _move_joints(self, q, what):
            moving["name"] = f"move_joints: {what}"
            return move_joints(self, q, what)

        def dump_here(path):
            if dump:
                try:
                    _dump(runner, moving.get("traj"), path)
                except Exception as ex:  # noqa: BLE001
                    log.append(f"dump failed: {ex}")

        def _event(kind, detail="", t=None):
            if kind == "motion" and "collision:" in detail:
                events.append(describe(runner, moving["name"], detail))
                dump_here(f"{dump}_{len(events)}.pkl")
                log.append(f"COLLISION {moving['name']}: {detail}")
            elif kind == "motion" and "will stop" in detail:  # a stop other than a collision: described if protective
                moving["stop"] = describe(runner, moving["name"], detail)
            elif kind == "protective_stop" and "collision:" not in detail:
                rec = moving.pop("stop", None) or {"motion": moving["name"], "detail": detail}
                stops.append(rec)
                dump_here(f"{dump}_stop{len(stops)}.pkl")
                log.append(f"PROTECTIVE_STOP {moving['name']}: {detail}")
            return event(kind, detail, t)

        def _log(self, kind, name, /, **payload):
            if kind in ("note", "result") and name != "arm.execute_trajectory":
                short = {k: (np.round(np.asarray(v, float), 3).tolist() if isinstance(v, np.ndarray) else v)
                         for k, v in payload.items() if k not in ("q", "timings_ms")}
                log.append(f"{self.state} {kind} {name} {short}"[:400])
            return note(self, kind, name, **payload)

        cls._run_trajectory, cls._move_joints, arm._event, cls._log = _run_trajectory, _move_joints, _event, _log

    rep = run_task(cfg, task, seed, progress=False, oracle_perception=oracle, journal_path=False, runner_hook=hook)
    return {"task": task, "seed": seed, "delivered": rep.truth["end"]["delivered"],
            "wanted": rep.truth["start"]["in_sink"], "collisions": rep.collisions, "events": events,
            "protective_stops": rep.protective_stops, "stops": stops, "log": log}


def _dump(runner, traj, path: str) -> None:
    """What the planner knew and what was there at a collision, pickled for replay: the belief's objects, the map
    (with its marks count), the item in hand, the trajectory and the simulator's objects."""
    import pickle

    from kitchenbot.planning.types import marks_of

    w, b = runner.robot.arm.world, runner.belief
    M = b.map_points
    with open(path, "wb") as f:
        pickle.dump({"objects": b.scene_objects(), "map": None if M is None else np.asarray(M), "marks": marks_of(M),
                     "target": runner.item.obj if runner.item is not None else None,
                     "grasp": runner.item.pick.grasp if runner.item is not None and runner.item.pick is not None else None,
                     "traj": None if traj is None else np.asarray(traj.q),
                     "sim": {u: (so.model.obj_id, so.T_base_obj) for u, so in w.objects.items()},
                     "held_uid": w.held_uid, "T_tcp_held": w.T_tcp_held, "q": np.asarray(w.q)}, f)


def describe(runner, motion: str | None, detail: str) -> dict:
    w = runner.robot.arm.world
    rec: dict = {"motion": motion, "detail": detail, "state": runner.state, "target": None, "objects": []}
    it = runner.item.obj if runner.item is not None else None
    if it is not None:
        rec["target"] = {"cls": it.cls, "p": np.round(it.T_base_obj[:3, 3], 3).tolist(), "iid": it.instance_id}
        pick = runner.item.pick
        if w.held_uid is not None and pick is not None:  # the held item in the hand: as planned against as it is
            g = pick.grasp  # E: the true item's pose in the planned item's frame
            E = np.linalg.inv(g.obj.T_base_obj) @ g.T_base_tcp @ w.T_tcp_held
            rec["in_hand"] = {"grasp": pick.grasp.spec.name, "width": round(float(pick.grasp.spec.width), 4),
                              "opening": round(float(w.gripper_opening), 4),
                              "err_cm": round(100 * float(np.linalg.norm(E[:3, 3])), 2),
                              "rot_deg": round(float(np.degrees(rotation_angle(E[:3, :3]))), 1)}
    for uid, so in w.objects.items():
        p = so.T_base_obj[:3, 3]
        near = [o for o in runner.belief.scene_objects() if o.obj_id == so.model.obj_id]
        best = min(near, key=lambda o: np.linalg.norm(o.T_base_obj[:3, 3] - p), default=None)
        e = {"uid": uid, "cls": so.model.cls, "true_p": np.round(p, 3).tolist(), "held": uid == w.held_uid}
        if best is not None and np.linalg.norm(best.T_base_obj[:3, 3] - p) < 0.1:
            R = best.T_base_obj[:3, :3].T @ so.T_base_obj[:3, :3]
            e.update(err_cm=round(100 * float(np.linalg.norm(best.T_base_obj[:3, 3] - p)), 2),
                     rot_deg=round(float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))), 1),
                     visible=round(best.visible_fraction, 2), verification=round(best.verification, 2),
                     points=len(best.points) if best.points is not None else 0, iid=best.instance_id,
                     prov=runner.belief.provenance(best))
        else:
            e["perceived"] = False
        rec["objects"].append(e)
    try:
        rec["hidden"] = [hidden(runner, int(u)) for u in re.findall(r"obj:(\d+)", detail) if int(u) in w.objects]
    except Exception as ex:  # the trace matters more than this summary
        rec["hidden"] = f"{type(ex).__name__}: {ex}"
    return rec


def hidden(runner, uid: int) -> dict:
    """How the item `uid` (truth) stood in what the planner checks when it was hit: the share of its true surface
    the fused map holds a point near (5 mm), and of its map points (within 5 mm of its true surface) how many the
    lift's scene leaves unexplained, which belief items explain the rest, and the share of its surface within a
    voxel's reach of an obstacle voxel or a believed item's model."""
    from kitchenbot.planning.collision import SceneObject, _surface_distance
    from kitchenbot.planning.types import marks_of

    w, pl, b = runner.robot.arm.world, runner.planner, runner.belief
    so = w.objects[uid]
    S = np.asarray(so.model.mesh.sample_points_uniformly(1500).points)
    S = S @ so.T_base_obj[:3, :3].T + so.T_base_obj[:3, 3]
    M = b.map_points
    if M is None or len(M) == 0:
        return {"uid": uid, "map_points": 0}
    n = len(M) - marks_of(M)
    P = np.asarray(M)[:n]
    from scipy.spatial import cKDTree

    seen = cKDTree(P).query(S, distance_upper_bound=0.005)[0] < 0.005
    dl = _surface_distance(so.model, (P - so.T_base_obj[:3, 3]) @ so.T_base_obj[:3, :3])
    mine = P[dl < 0.005]
    known = [o for o in b.scene_objects() if o.obj_id in pl.inventory.models]
    target = runner.item.obj if runner.item is not None else None
    own = [o for o in known if o is target]
    sobj = [SceneObject(str(o.instance_id), pl.inventory[o.obj_id], o.T_base_obj) for o in known]
    ex = pl.world.explained(mine, sobj, instance_points=[o.points for o in known],
                            self_explaining=[any(o is x for x in own) for o in known]) if len(mine) else np.zeros(0, bool)
    by = {}
    for o, s in zip(known, sobj):
        if len(mine) and ex.any():
            d = _surface_distance(s.model, (mine[ex] - s.T_base_obj[:3, 3]) @ s.T_base_obj[:3, :3])
            k = int((d < 0.015).sum())
            if k:
                by[f"{o.cls}#{o.instance_id}{'(target)' if o is target else ''}"] = k
    inst = {}
    for o in known:
        if o.points is not None and len(o.points) and len(mine):
            k = int((cKDTree(np.asarray(o.points)).query(mine, distance_upper_bound=1e-4)[0] < 1e-4).sum())
            if k:
                inst[f"{o.cls}#{o.instance_id}"] = k
    vox = pl._voxels(M, known, own=own)
    covered = (cKDTree(vox).query(S, distance_upper_bound=0.02)[0] < 0.02) if len(vox) else np.zeros(len(S), bool)
    modeled = np.zeros(len(S), bool)
    for s in sobj:
        modeled |= _surface_distance(s.model, (S - s.T_base_obj[:3, 3]) @ s.T_base_obj[:3, :3]) < 0.01
    return {"uid": uid, "cls": so.model.cls, "surface_seen": round(float(seen.mean()), 3), "map_points": int(len(mine)),
            "unexplained": int((~ex).sum()), "explained_by": by, "in_instances": inst,
            "surface_near_voxel": round(float(covered.mean()), 3), "surface_near_a_model": round(float(modeled.mean()), 3),
            "surface_in_neither": round(float((~covered & ~modeled).mean()), 3)}


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description="trace the collisions of one simulated task run")
    ap.add_argument("task")
    ap.add_argument("seed", type=int)
    ap.add_argument("--slip", type=float, default=0.05, help="as `kitchenbot bench tasks --slip`")
    ap.add_argument("--objects", type=int, default=None, help="as `kitchenbot bench tasks --objects`")
    ap.add_argument("--oracle-perception", action="store_true", help="as `kitchenbot bench tasks`")
    ap.add_argument("--dump", default=None, help="pickle what the planner knew at each collision to DUMP_k.pkl")
    a = ap.parse_args()
    print(json.dumps(main(a.task, a.seed, a.slip, a.objects, a.oracle_perception, a.dump), indent=1))
