"""Calibrate the verification threshold (perception/verify.py) on a BOP dataset with world poses, e.g. generated
scenes with distractors (`kitchenbot scenes generate --distractors 3`):

    python -m kitchenbot.perception.calibrate_verify DATASET [--cell always|never|auto] [--out table.json]

Every scan is perceived with no verification threshold; each pose is labelled right (within 0.1 diameter ADI
of a ground-truth object of its model in the base frame, all objects of the scan counted, however little
seen) or wrong (on a distractor, a phantom, or off); a wrong pose with at least 20 % of its posed model points
within 15 mm of a distractor's posed surface (the dataset's objects outside the inventory, e.g.
`models_distractors/`) is labelled with that distractor's name. Printed: for each threshold, the right poses
kept and the wrong ones kept (of them, on distractors).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from kitchenbot.perception import bop
from kitchenbot.perception.evaluate import _on_distractor, load_inventory
from kitchenbot.world.cell import Cell
from kitchenbot.perception.metrics import adi
from kitchenbot.perception.pipeline import Perceiver
from kitchenbot.perception.settings import PerceptionSettings


def collect(dataset: Path, use_cell: str = "always", settings: PerceptionSettings | None = None,
            cell: Cell | None = None) -> list[dict]:
    """One row per pose: its verification parts and whether it is right."""
    inventory, distractor_pts, distractor_names = load_inventory(dataset)
    settings = (settings or PerceptionSettings()).model_copy(update={"verify_threshold": 0.0})
    perceiver = Perceiver(settings, inventory, cell or Cell(), use_cell=use_cell)
    rows = []
    for sd in bop.scene_dirs(dataset):
        images = bop.read_scene(sd)
        if not all(im.has_world_pose for im in images):
            continue
        res = perceiver.perceive([im.view for im in images])
        gt, others = [], []
        for im in images:
            for g in im.gt:
                if g.obj_id in inventory.models:
                    gt.append((g.obj_id, im.view.T_base_cam @ g.T_cam_obj))
                elif g.obj_id in distractor_pts:
                    T = im.view.T_base_cam @ g.T_cam_obj
                    others.append((g.obj_id, distractor_pts[g.obj_id] @ T[:3, :3].T + T[:3, 3]))
        for p in res.poses:
            m = inventory[p.obj_id]
            pts = m.points[::4]
            err = min((adi(p.T_base_obj, T, pts) for o, T in gt if o == p.obj_id), default=np.inf)
            # Near some inventory item (a wrong fit of dishware) or not (a distractor, a phantom).
            near = min((np.linalg.norm(p.T_base_obj[:3, 3] - T[:3, 3]) for _, T in gt), default=np.inf)
            k = _on_distractor(p.T_base_obj, pts, others)
            rows.append({"scene": int(images[0].scene_id), "obj_id": p.obj_id, "verification": p.verification,
                         "score": p.score, "right": bool(err < 0.1 * m.diameter),
                         "near_dishware": bool(near < 0.5 * m.diameter),
                         "on_distractor": distractor_names[others[k][0]] if k >= 0 else None, **p.checks})
    return rows


def table(rows: list[dict], thresholds=np.round(np.arange(0.0, 0.96, 0.05), 2)) -> list[dict]:
    v = np.array([r["verification"] for r in rows])
    ok = np.array([r["right"] for r in rows], bool)
    dis = np.array([r.get("on_distractor") is not None for r in rows], bool)
    return [{"threshold": float(t), "right_kept": int(np.sum(ok & (v >= t))), "wrong_kept": int(np.sum(~ok & (v >= t))),
             "on_distractors_kept": int(np.sum(dis & (v >= t)))} for t in thresholds]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("dataset", type=Path, nargs="+")
    ap.add_argument("--cell", default="always", choices=["always", "never", "auto"])
    ap.add_argument("--out", type=Path, help="write the rows and the table as JSON")
    a = ap.parse_args(argv)
    rows = [r for d in a.dataset for r in collect(d, a.cell)]
    tab = table(rows)
    print(f"{len(rows)} poses, {sum(r['right'] for r in rows)} right, "
          f"{sum(r['on_distractor'] is not None for r in rows)} on distractors")
    for t in tab:
        print(f"  threshold {t['threshold']:.2f}: right kept {t['right_kept']:4d}  wrong kept {t['wrong_kept']:4d}"
              f"  (on distractors {t['on_distractors_kept']:3d})")
    if a.out:
        a.out.write_text(json.dumps({"rows": rows, "table": tab}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
