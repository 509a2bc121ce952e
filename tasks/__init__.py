"""Tasks: what to pick, where to place it, when the work is done.

``TASKS`` maps the CLI names to the task classes; ``make_task(name, inventory, cell)`` builds one.
"""

from kitchenbot.tasks.base import Placed, Task
from kitchenbot.tasks.cup_stacking import CupStacking
from kitchenbot.tasks.sink_pick import SinkPick
from kitchenbot.tasks.sink_to_dishwasher import SinkToDishwasher

TASKS: dict[str, type[Task]] = {t.name: t for t in (SinkPick, SinkToDishwasher, CupStacking)}


def make_task(name: str, inventory, cell) -> Task:
    try:
        cls = TASKS[name]
    except KeyError:
        raise ValueError(f"unknown task {name!r}; expected one of {sorted(TASKS)}") from None
    return cls(inventory, cell)


__all__ = ["TASKS", "CupStacking", "Placed", "SinkPick", "SinkToDishwasher", "Task", "make_task"]
