"""Imports run one way: executive -> tasks -> planning -> perception -> world; drivers beside; fakes only from the
cell assembly (and the tests); benchmarks at the top. Read from the source with `ast`, so a lazy import inside
a function counts too."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# package -> the kitchenbot packages it may import (besides itself and the `transforms` and `jsonfile` helpers)
ALLOWED = {
    "world": set(),
    "drivers": set(),
    "calibration": {"drivers"},
    "perception": {"world", "drivers"},
    "planning": {"perception", "world", "drivers"},
    "tasks": {"planning", "perception", "world", "drivers"},
    "fakes": {"world", "drivers"},
    "executive": {"tasks", "planning", "perception", "world", "drivers", "calibration", "fakes"},
    "bench": {"executive", "tasks", "planning", "perception", "world", "drivers", "calibration", "fakes"},
}
# the only executive modules that may build the simulator: the cell assembly, and `scenes generate` (it writes
# simulated datasets)
FAKES_USERS = {"executive/assembly.py", "executive/commands/scenes.py"}


def imports_of(path: Path) -> set[str]:
    """The kitchenbot packages a module imports (``kitchenbot.X...`` -> X), anywhere in the file."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        out |= {n.split(".")[1] for n in names if n.startswith("kitchenbot.") and n.count(".") >= 1}
    return out


def violations() -> list[str]:
    bad = []
    for package, allowed in ALLOWED.items():
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            for target in imports_of(path) - {package, "transforms", "jsonfile"}:
                if target not in allowed:
                    bad.append(f"{rel} imports kitchenbot.{target}")
                elif target == "fakes" and package == "executive" and rel not in FAKES_USERS:
                    bad.append(f"{rel} imports kitchenbot.fakes (only {sorted(FAKES_USERS)} may)")
    return bad


def test_every_package_is_covered():
    packages = {p.name for p in ROOT.iterdir() if (p / "__init__.py").is_file() and p.name not in ("tests", "scripts")}
    assert packages == set(ALLOWED), packages ^ set(ALLOWED)


def test_imports_run_one_way():
    assert violations() == []


def test_the_check_catches_an_upward_import(tmp_path):
    """The walker sees a lazy upward import (world importing planning inside a function)."""
    bad = tmp_path / "m.py"
    bad.write_text("def f():\n    from kitchenbot.planning.grasps import select_grasps\n    import kitchenbot.world.cell\n")
    assert imports_of(bad) == {"planning", "world"}
