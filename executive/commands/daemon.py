"""`kitchenbot daemon [--config FILE] [--host 127.0.0.1] [--port 8765]`: the local HTTP API (see executive/daemon.py)."""

from __future__ import annotations

import argparse
import ipaddress
import sys


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("daemon", help="serve the local HTTP API (start/stop/pause tasks, status, history, events)")
    p.add_argument("--config", help="cell config YAML (default: the shipped simulation config)")
    p.add_argument("--host", default="127.0.0.1", help="bind address (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8765)
    p.add_argument("--token-file", help="token file (default: $KITCHENBOT_STATE_DIR/token; env KITCHENBOT_TOKEN wins)")
    p.add_argument("--sim", action="store_true", help="use the simulated cell whatever the config says")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from kitchenbot.executive.daemon import create_app, load_token
    from kitchenbot.executive.journal import default_journal_path

    if not (0 < args.port < 65536):
        raise ValueError(f"--port {args.port}: expected 1..65535")
    cfg_args = argparse.Namespace(config=args.config, sim=args.sim, objects=None)
    from kitchenbot.executive.commands.run import load_run_config

    cfg = load_run_config(cfg_args)
    token = load_token(args.token_file)
    try:
        loopback = ipaddress.ip_address(args.host).is_loopback
    except ValueError:
        loopback = args.host == "localhost"
    if not loopback:
        print(f"warning: binding to {args.host}: the API is reachable from the network (token still required "
              "to move the robot)", file=sys.stderr)
    app = create_app(cfg, token=token)
    print(f"kitchenbot daemon on http://{args.host}:{args.port} (OpenAPI at /docs); token from "
          f"{'KITCHENBOT_TOKEN' if 'KITCHENBOT_TOKEN' in __import__('os').environ else args.token_file or default_journal_path(False).parent / 'token'}",
          file=sys.stderr)
    uvicorn.run(app, host=args.host, port=args.port, log_level="info")
    return 0
