"""`kitchenbot calibrate`: hand-eye calibration (Park–Martin) of the wrist camera.

    kitchenbot calibrate [--sim] --out FILE.yaml [--config FILE] [--samples N] [--seed S]
        run the capture routine (eye in hand) from where the arm stands; --sim runs it in the simulated cell
        with a hidden, perturbed camera mount and reports the error against it
    kitchenbot calibrate solve SAMPLES.json --out FILE.yaml
        solve recorded samples ({"mount": ..., "samples": [{"T_base_flange", "T_cam_board"}, ...]})
    kitchenbot calibrate board --out BOARD.png [--dpi 300]
        the ChArUco board image to print at 100 % scale

Set `calibration.file` in the cell config to the written YAML to use the result.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="hand-eye calibration: run the capture routine, solve recorded samples, or print the board",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("action", nargs="?", default="run", choices=["run", "solve", "board"],
                   help="run (default): capture and solve; solve: recorded SAMPLES.json; board: write the board image")
    p.add_argument("samples_file", nargs="?", metavar="SAMPLES", help="recorded samples JSON (for `solve`)")
    p.add_argument("--out", required=True, help="output YAML (run/solve) or PNG (board)")
    p.add_argument("--config", help="cell config YAML (default: the shipped simulation config)")
    p.add_argument("--sim", action="store_true", help="run in the simulated cell (fake arm and camera)")
    p.add_argument("--samples", type=int, default=15, help="viewpoints to capture (default 15)")
    p.add_argument("--seed", type=int, default=0, help="random seed for viewpoints (and the simulated mount error)")
    p.add_argument("--no-reject", action="store_true", help="keep every pair (no MAD outlier rejection)")
    p.add_argument("--no-refine", action="store_true",
                   help="report Park–Martin's X as is (no refinement on the corner pixels)")
    p.add_argument("--save-samples", metavar="JSON", help="also write the captured samples (for `solve`)")
    p.add_argument("--board-squares", default="8x6", help="ChArUco squares as XxY (default 8x6)")
    p.add_argument("--square", type=float, default=0.030, help="square side, metres (default 0.030)")
    p.add_argument("--marker", type=float, default=0.022, help="marker side, metres (default 0.022)")
    p.add_argument("--dictionary", default="DICT_5X5_100", help="ArUco dictionary (default DICT_5X5_100)")
    p.add_argument("--dpi", type=float, default=300.0, help="board image resolution for `board` (default 300)")
    p.set_defaults(func=run)


def board_spec(args: argparse.Namespace):
    from kitchenbot.calibration.board import CharucoSpec

    try:
        sx, sy = (int(v) for v in args.board_squares.lower().split("x"))
    except ValueError:
        raise ValueError(f"--board-squares: expected XxY such as 8x6, got {args.board_squares!r}") from None
    try:
        return CharucoSpec(squares_x=sx, squares_y=sy, square_m=args.square, marker_m=args.marker,
                           dictionary=args.dictionary)
    except Exception as e:  # pydantic's ValidationError: one line per field
        raise ValueError(f"board: {e}") from None


def run(args: argparse.Namespace) -> int:
    if args.action == "solve":
        return _solve(args)
    if args.samples_file:
        raise ValueError(f"unexpected argument {args.samples_file!r}: a samples file is only read by `calibrate solve`")
    if args.action == "board":
        return _board(args)
    return _run_routine(args)


# ---- solve ------------------------------------------------------------------------------------------------------
def _solve(args: argparse.Namespace) -> int:
    from kitchenbot.calibration.files import load_corners, load_samples, save_hand_eye
    from kitchenbot.calibration.refine import refine_reprojection
    from kitchenbot.calibration.residuals import evaluate, solve_robust

    if not args.samples_file:
        raise ValueError("calibrate solve: expected a SAMPLES.json argument")
    mount, F, C = load_samples(args.samples_file)
    corners = load_corners(args.samples_file)
    result = solve_robust(F, C, mount, reject=not args.no_reject)
    extra: dict = {"source": {"samples_file": str(Path(args.samples_file).resolve())}}
    if corners is not None and not args.no_refine:
        pm = result
        used = pm.samples_used
        ref = refine_reprojection(pm.X, pm.spread.mean, [F[k] for k in used], [corners.object_points[k] for k in used],
                                  [corners.image_points[k] for k in used], corners.K, corners.dist, mount)
        result = evaluate(ref.X, F, C, mount, pm.pairs_used, pm.pairs_rejected, method="park_martin_1994+reprojection")
        extra["refinement"] = {"reprojection_rms_px_before": ref.rms_px_before,
                               "reprojection_rms_px_after": ref.rms_px_after, "corners": ref.n_points}
        extra["park_martin"] = {pm.name: pm.X.tolist(), "residuals": {"rotation_deg": pm.rotation_deg_mean,
                                                                      "translation_mm": pm.translation_mm_mean}}
        print(f"refined on {ref.n_points} corner pixels: reprojection {ref.rms_px_before:.3f} -> "
              f"{ref.rms_px_after:.3f} px rms")
    save_hand_eye(args.out, result, extra)
    _print_result(result)
    print(f"wrote {args.out}")
    return 0


# ---- board ------------------------------------------------------------------------------------------------------
def _board(args: argparse.Namespace) -> int:
    import cv2

    from kitchenbot.calibration.board import render_board

    spec = board_spec(args)
    ppm = args.dpi / 0.0254
    # Whole pixels per square keep the printed squares exact; the DPI is adjusted to match.
    sq_px = max(20, round(spec.square_m * ppm))
    ppm = sq_px / spec.square_m
    margin = round(0.01 * ppm)
    img = render_board(spec, ppm, margin)
    if not cv2.imwrite(str(args.out), img, [cv2.IMWRITE_PNG_COMPRESSION, 9]):
        raise ValueError(f"--out {args.out}: could not write the image (expected a .png path in a writable folder)")
    w, h = spec.size_m
    print(f"wrote {args.out}: {img.shape[1]}x{img.shape[0]} px at {ppm * 0.0254:.1f} dpi; print at 100 % so the "
          f"board measures {w * 1000:.0f} x {h * 1000:.0f} mm (squares {spec.square_m * 1000:.1f} mm)")
    return 0


# ---- the capture routine ---------------------------------------------------------------------------------------
def _run_routine(args: argparse.Namespace) -> int:
    from kitchenbot.calibration.files import Corners, save_hand_eye, save_samples
    from kitchenbot.calibration.routine import RoutineSettings, run_routine, tool_spheres
    from kitchenbot.executive.config import load_config
    from kitchenbot.transforms import pose_error
    from kitchenbot.world.cell import Cell

    if args.samples < 3:
        raise ValueError(f"--samples: expected at least 3 viewpoints, got {args.samples}")
    cfg = load_config(args.config)
    spec = board_spec(args)
    nominal = cfg.T_flange_cam()  # the configured mount only steers the viewpoints
    if not args.sim and "fake" in (cfg.drivers.arm.kind, cfg.drivers.camera.kind):
        raise ValueError(f"{cfg.source}: the config uses the fake arm/camera; add --sim to calibrate in the "
                         "simulated cell, or configure the real drivers")
    if args.sim:
        from kitchenbot.executive.calibration_sim import make_calibration_sim

        sim = make_calibration_sim(cfg, spec, seed=args.seed)
        arm, camera, truth = sim.arm, sim.camera, sim.world.T_flange_cam
    else:
        arm, camera = _real_devices(cfg)
        truth = None
    settings = RoutineSettings(samples=args.samples, refine=not args.no_refine)

    def progress(rec) -> None:
        if rec.error:
            print(f"  view {rec.index:2d}: skipped ({rec.error})")
        else:
            print(f"  view {rec.index:2d}: {rec.n_corners} corners, reprojection {rec.rms_px:.3f} px")

    from kitchenbot.drivers.errors import DriverError

    try:
        report = run_routine(arm, camera, spec, nominal, settings, seed=args.seed, boxes=Cell(cfg.cell).boxes,
                             extra=tool_spheres(cfg.robot.tool.T_flange_tcp.matrix(), nominal), progress=progress)
    except DriverError as e:  # a protective stop, a lost link, a dropped frame: stop and say so
        print(f"kitchenbot calibrate: device error, calibration stopped: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    finally:
        camera.disconnect()
        arm.disconnect()
    for note in report.notes:
        print(f"note: {note}")
    extra = {
        "board": spec.model_dump(),
        "captures": [{"index": r.index, "q": [float(v) for v in r.q], "corners": r.n_corners,
                      "rms_px": None if r.error else float(r.rms_px), "error": r.error} for r in report.records],
    }
    if report.refinement is not None:
        ref = report.refinement
        extra["refinement"] = {"reprojection_rms_px_before": ref.rms_px_before,
                               "reprojection_rms_px_after": ref.rms_px_after, "corners": ref.n_points}
        extra["park_martin"] = {"T_flange_cam": report.park_martin.X.tolist(),
                                "residuals": {"rotation_deg": report.park_martin.rotation_deg_mean,
                                              "translation_mm": report.park_martin.translation_mm_mean}}
    if truth is not None:
        r, t = pose_error(report.result.X, truth)
        extra["simulation"] = {"true_T_flange_cam": np.asarray(truth).tolist(),
                               "error_deg": float(np.rad2deg(r)), "error_mm": float(t * 1000),
                               "arm_collisions": int(arm.log.collisions),
                               "arm_protective_stops": int(arm.log.protective_stops)}
        if report.refinement is not None:
            r0, t0 = pose_error(report.park_martin.X, truth)
            extra["simulation"].update(park_martin_error_deg=float(np.rad2deg(r0)), park_martin_error_mm=float(t0 * 1000))
    save_hand_eye(args.out, report.result, extra)
    if args.save_samples:
        ok = [r for r in report.records if r.T_cam_board is not None]
        corners = Corners(ok[0].K, None, [r.object_points for r in ok], [r.image_points for r in ok])
        save_samples(args.save_samples, "eye_in_hand", [r.T_base_flange for r in ok], [r.T_cam_board for r in ok],
                     corners=corners)
    if report.refinement is not None:
        ref = report.refinement
        print(f"refined on {ref.n_points} corner pixels: reprojection {ref.rms_px_before:.3f} -> "
              f"{ref.rms_px_after:.3f} px rms")
    _print_result(report.result)
    if truth is not None:
        sim = extra["simulation"]
        line = f"simulation: error against the hidden mount {sim['error_deg']:.4f} deg, {sim['error_mm']:.3f} mm"
        if "park_martin_error_deg" in sim:
            line += (f" (Park–Martin alone {sim['park_martin_error_deg']:.4f} deg, "
                     f"{sim['park_martin_error_mm']:.3f} mm)")
        print(line)
    print(f"wrote {args.out}")
    return 0


def _real_devices(cfg):
    """The configured arm and camera (the executive's cell assembly), connected."""
    from kitchenbot.executive.assembly import assemble

    cell = assemble(cfg)
    cell.arm.connect()
    cell.camera.connect()
    return cell.arm, cell.camera


def _print_result(result) -> None:
    s = result.summary()
    X = result.X
    print(f"{result.name} ({result.mount}, {result.method}, {len(result.samples_used)}/{result.n_samples} samples, "
          f"{s['pairs_used']} pairs, {len(s['pairs_rejected'])} rejected):")
    for row in X:
        print("  [" + ", ".join(f"{v: .6f}" for v in row) + "]")
    print(f"residuals AX=XB: rotation {s['rotation_deg']:.4f} deg mean ({s['rotation_deg_max']:.4f} max), "
          f"translation {s['translation_mm']:.3f} mm mean ({s['translation_mm_max']:.3f} max)")
    b = s["board_spread"]
    print(f"board spread ({b['frame']}): {b['translation_rms_mm']:.3f} mm rms, {b['rotation_rms_deg']:.4f} deg rms")
    sys.stdout.flush()


__all__ = ["register", "run", "board_spec"]
