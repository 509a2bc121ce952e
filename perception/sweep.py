"""`kitchenbot eval DATASET --sweep-models`: every combination of backends whose weights are present, with and
without 2D-3D feature fusion, as a table in the layout of the paper's Table 1 (markdown + CSV).

Rows: visual model (image encoder) x feature setting ("without fusion": image class tokens for the candidate
proposal only, point features for registration; "with fusion": fused features for registration too).
Column groups: detector + segmenter. Columns: point encoders (fpfh and every plug-in that resolves by name).
A combination whose weights (or packages) are missing is not run; its cell says "skipped" and the notes
under the table say why. Unlike the paper's table, ICP refinement stays on (the pipeline always refines).
"""

from __future__ import annotations

import argparse
import csv
import time
from dataclasses import dataclass, field
from pathlib import Path

DETECTOR_GROUPS: list[tuple[str, str, str]] = [
    ("geometric", "geometric", "Geometric"),
    ("llmdet", "sam2", "LLMDet + SAM2"),
    ("grounding-dino", "sam2", "GroundingDINO + SAM2"),
]
VISUAL = {"none": "None", "colour": "Colour", "dinov2": "DINOv2", "beit": "BEiT", "clip": "CLIP"}


@dataclass
class Combo:
    detector: str
    segmenter: str
    image_encoder: str
    point_encoder: str
    fusion: bool

    @property
    def key(self) -> str:
        return f"{self.detector}+{self.segmenter}/{self.image_encoder}/{self.point_encoder}/" + (
            "fusion" if self.fusion else "no-fusion")


@dataclass
class SweepRow:
    combo: Combo
    status: str  # ok | skipped | failed
    reason: str = ""
    adi: float = float("nan")
    auc: float = float("nan")
    pose_ms: float = float("nan")
    scan_ms: float = float("nan")
    wall_s: float = 0.0
    extra: dict = field(default_factory=dict)


def combinations(point_encoders: list[str], visual: list[str] | None = None,
                 groups: list[tuple[str, str, str]] | None = None) -> list[Combo]:
    """All combinations; 'none' (no image encoder) appears only without fusion (there is nothing to fuse)."""
    out = []
    for det, seg, _ in groups or DETECTOR_GROUPS:
        for img in visual or list(VISUAL):
            for fusion in ((False,) if img == "none" else (False, True)):
                for pe in point_encoders:
                    out.append(Combo(det, seg, img, pe, fusion))
    return out


def unavailable(combo: Combo, weights_dir: str) -> str:
    """Why a combination cannot run here ('' when it can)."""
    from kitchenbot.perception.backends import backend_available

    why = []
    for name in dict.fromkeys((combo.detector, combo.segmenter, combo.image_encoder)):
        ok, reason = backend_available(name, weights_dir)
        if not ok:
            why.append(f"{name}: {reason}")
    return "; ".join(why)


def run_sweep(dataset: str | Path, settings, point_encoders: list[str] | None = None, visual: list[str] | None = None,
              log=print, **eval_kw) -> list[SweepRow]:
    """Evaluate every available combination (`evaluate` of evaluate.py, same keywords) and return the rows."""
    from kitchenbot.perception.evaluate import evaluate
    from kitchenbot.perception.hf_common import device_and_dtype
    from kitchenbot.perception.plugins import point_encoder_names

    pes = point_encoders or sorted(point_encoder_names(), key=lambda n: (n != "fpfh", n))
    try:
        device = str(device_and_dtype()[0])
    except ImportError:
        device = "cpu"
    rows = []
    combos = combinations(pes, visual)
    for k, c in enumerate(combos):
        why = unavailable(c, settings.weights_dir)
        if why:
            rows.append(SweepRow(c, "skipped", why))
            continue
        s = settings.model_copy(update={"detector": c.detector, "segmenter": c.segmenter,
                                        "image_encoder": c.image_encoder, "point_encoder": c.point_encoder,
                                        "fusion": c.fusion})
        t0 = time.perf_counter()
        try:
            r = evaluate(dataset, s, **eval_kw).report
        except (ValueError, FileNotFoundError, RuntimeError, ImportError) as e:
            rows.append(SweepRow(c, "failed", f"{type(e).__name__}: {e}", wall_s=time.perf_counter() - t0))
            log(f"[{k + 1}/{len(combos)}] {c.key}: failed: {e}")
            continue
        row = SweepRow(c, "ok", "", r["adi_recall_0.1d"], r["auc_adds_10cm"], r["pose_ms_per_object_median"],
                       r["scan_ms_median"], time.perf_counter() - t0, {"device": device, "objects": r["objects"]})
        rows.append(row)
        log(f"[{k + 1}/{len(combos)}] {c.key}: ADI {100 * row.adi:.2f} %  AUC {row.auc:.3f}  "
                 f"{row.pose_ms:.0f} ms/object  ({row.wall_s:.0f} s)")
    return rows


def _cell(row: SweepRow | None) -> str:
    if row is None:
        return "-"
    if row.status == "ok":
        return f"{100 * row.adi:.2f}"
    return row.status


def table_markdown(rows: list[SweepRow], title: str = "") -> str:
    """Paper Table 1 layout: visual model x feature setting rows, (detector + segmenter) x point encoder columns."""
    by = {r.combo.key: r for r in rows}
    pes = list(dict.fromkeys(r.combo.point_encoder for r in rows))
    groups = [g for g in DETECTOR_GROUPS if any((r.combo.detector, r.combo.segmenter) == g[:2] for r in rows)]
    visual = [v for v in VISUAL if any(r.combo.image_encoder == v for r in rows)]
    head = ["Visual model", "Feature setting"] + [f"{g[2]}: {pe}" for g in groups for pe in pes]
    lines = [f"### {title}" if title else "", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for v in visual:
        for fusion in ((False,) if v == "none" else (False, True)):
            cells = [VISUAL[v], "with fusion" if fusion else "without fusion"]
            for det, seg, _ in groups:
                for pe in pes:
                    cells.append(_cell(by.get(Combo(det, seg, v, pe, fusion).key)))
            lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "ADI recall (%) at 0.1 x diameter. ICP refinement on (the paper's Table 1 has it off)."]
    skipped: dict[str, int] = {}
    for r in rows:
        if r.status == "skipped":
            for part in r.reason.split("; "):
                skipped[part] = skipped.get(part, 0) + 1
    failed = [r for r in rows if r.status == "failed"]
    if skipped:
        lines += ["", f"Skipped ({sum(r.status == 'skipped' for r in rows)} combinations; `kitchenbot models` "
                  "says how to fetch weights):"]
        lines += [f"- {why} (needed by {n})" for why, n in skipped.items()]
    if failed:
        lines += ["", "Failed:"] + [f"- {r.combo.key}: {r.reason}" for r in failed]
    devs = {r.extra.get("device") for r in rows if r.status == "ok"}
    if devs and devs <= {"cpu"}:
        lines += ["", "Timings were taken on the CPU; no CUDA device was available, so no CUDA timings."]
    return "\n".join(lines).lstrip() + "\n"


def write_csv(rows: list[SweepRow], path: str | Path) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["detector", "segmenter", "image_encoder", "point_encoder", "fusion", "status", "adi_recall_0.1d",
                    "auc_adds_10cm", "pose_ms_per_object", "scan_ms", "wall_s", "device", "reason"])
        for r in rows:
            c = r.combo
            w.writerow([c.detector, c.segmenter, c.image_encoder, c.point_encoder, int(c.fusion), r.status,
                        f"{r.adi:.4f}", f"{r.auc:.4f}", f"{r.pose_ms:.1f}", f"{r.scan_ms:.1f}", f"{r.wall_s:.1f}",
                        r.extra.get("device", ""), r.reason])


# ---- CLI glue (the flag lives on `kitchenbot eval`) --------------------------------------------------------
def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--sweep-models", action="store_true",
                   help="evaluate every backend combination whose weights are present, with and without fusion; "
                        "write a Table-1 style table (markdown + CSV)")
    p.add_argument("--sweep-table", type=Path, default=Path("sweep_models"),
                   help="--sweep-models output path without suffix (writes .md and .csv; default: sweep_models)")
    p.add_argument("--point-encoders", nargs="+", metavar="NAME",
                   help="--sweep-models: point encoders to use (default: fpfh and every registered plug-in)")


def run_cli(args: argparse.Namespace, settings, eval_kw: dict) -> int:
    rows = run_sweep(args.dataset, settings, args.point_encoders, **eval_kw)
    md, cs = args.sweep_table.with_suffix(".md"), args.sweep_table.with_suffix(".csv")
    md.parent.mkdir(parents=True, exist_ok=True)
    text = table_markdown(rows, f"Backend combinations on {args.dataset}")
    md.write_text(text)
    write_csv(rows, cs)
    print(text)
    print(f"table: {md}  {cs}")
    return 0
