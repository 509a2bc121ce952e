"""`kitchenbot inventory [--config FILE] [--models DIR]`: the configured inventory as the robot will use it: per
model its class (and where it came from: the config, a grasps file or the mesh's shape, with the measures), its
size and how many grasps it has (synthesising and caching them for meshes that bring none)."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("inventory", help="list the inventory's models: class from the mesh's shape, grasps")
    p.add_argument("--config", help="cell config YAML (default: shipped)")
    p.add_argument("--models", help="a BOP models/ folder to list instead of the config's inventory")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from kitchenbot.executive.assembly import load_inventory
    from kitchenbot.executive.config import InventoryConfig, load_config
    from kitchenbot.planning.grasp_synthesis import ensure_grasps
    from kitchenbot.world.shape import classify

    cfg = load_config(args.config)
    if args.models:
        cfg = cfg.model_copy(update={"inventory": InventoryConfig(models_dir=args.models)})
    inventory = load_inventory(cfg)
    overrides = cfg.inventory.classes
    ensure_grasps(inventory, cfg.planning.grasp_cache_dir)
    print(f"inventory {inventory.source}: {len(inventory)} models")
    for m in inventory:
        shape = classify(m.mesh)
        if m.obj_id in overrides:
            origin = "config"
        elif m.dish is not None:
            origin = "builtin"
        elif m.cls != shape.cls:
            origin = "grasps file"
        else:
            origin = "shape"
        size = " x ".join(f"{v * 1000:.0f}" for v in m.extents)
        print(f"{m.obj_id:>4}  {m.name:<16} {m.cls:<6} ({origin}; {shape.describe()})  {size} mm  "
              f"{len(m.grasps)} grasps{'  round' if m.is_rotationally_symmetric else ''}")
    return 0
