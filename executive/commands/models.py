"""`kitchenbot models [--config FILE] [--weights-dir DIR]`: every perception backend, where its weights are
expected, whether they are present, and the command that fetches missing ones on a connected machine."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("models", help="list the perception backends and whether their weights are present")
    p.add_argument("--config", help="cell config YAML (default: shipped); its perception.weights_dir is used")
    p.add_argument("--weights-dir", help="look here instead of the config's perception.weights_dir")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from kitchenbot.executive.config import load_config
    from kitchenbot.perception.backends import CHECKPOINTS, backend_status, learned_available

    cfg = load_config(args.config)
    st = cfg.perception
    wdir = args.weights_dir or st.weights_dir
    rows = backend_status(wdir)
    configured = {"detector": st.detector, "segmenter": st.segmenter, "image_encoder": st.image_encoder,
                  "point_encoder": st.point_encoder}
    print(f"perception backends (weights_dir {wdir}; * = configured)")
    missing = []
    for r in rows:
        name = r.name + (" *" if configured.get(r.role) == r.name else "")
        status = "ready" if r.available else "MISSING"
        where = f"{r.checkpoint} in {r.path}" if r.name in CHECKPOINTS else f"no weights ({r.checkpoint})"
        print(f"  {r.role:<14} {name:<17} {status:<8} {where}")
        if not r.available:
            print(f"  {'':<14} {'':<17} {'':<8} {r.reason}")
            if r.name in CHECKPOINTS:
                missing.append(CHECKPOINTS[r.name])
    why = learned_available()
    if why:
        print(f"learned backends: {why}")
    if missing:
        print("Each folder needs " + CHECKPOINTS["grounding-dino"].layout() + " (tokenizer for detectors only).")
        print("Fetch missing weights on a connected machine (older huggingface_hub: `huggingface-cli download`), "
              "then copy the folders here:")
        for ck in missing:
            print(f"  {ck.fetch_command(wdir)}")
    bad = [r for r in rows if configured.get(r.role) == r.name and not r.available]
    return 1 if bad else 0
