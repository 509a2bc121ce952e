"""A live progress view of a run (rich): state, object k of n, attempts, recoveries, the last event."""

from __future__ import annotations

from rich.console import Console
from rich.live import Live
from rich.table import Table


class LiveProgress:
    def __init__(self, runner, console: Console | None = None):
        self.runner = runner
        self.console = console or Console(stderr=True)
        self.last = ""
        self.done, self.total = 0, 0
        self.obj = ""
        self.live = Live(self._render(), console=self.console, refresh_per_second=8, transient=False)

    def _render(self) -> Table:
        r = self.runner
        t = Table(show_header=False, box=None, title=f"kitchenbot {r.task.name}")
        t.add_row("state", f"[bold]{r.state}[/bold]")
        t.add_row("objects", f"{self.done} of {self.total} placed" + (f" (now: {self.obj})" if self.obj else ""))
        t.add_row("attempts / recoveries", f"{r.report.attempts} / {r.report.recoveries}")
        t.add_row("last", self.last)
        return t

    def on_event(self, ev: dict) -> None:
        self.done = ev.get("objects_done", self.done)
        self.total = max(ev.get("objects_total", self.total) or 0, self.done)
        kind = ev.get("type")
        if kind == "transition":
            self.last = f"{ev['source']} -> {ev['dest']} ({ev['trigger']})"
        elif kind == "fault":
            self.last = f"[red]fault {ev['kind']}[/red]: {ev['message'][:80]}"
        elif kind == "progress" and ev.get("object"):
            self.obj = ev["object"]
        elif kind == "placed":
            self.last = f"[green]placed {ev['object']}[/green]"
        self.live.update(self._render())

    def __enter__(self) -> "LiveProgress":
        self.live.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self.live.__exit__(*exc)


def print_summary(report, console: Console | None = None) -> None:
    c = console or Console()
    colour = {"succeeded": "green", "stopped": "yellow"}.get(report.status, "red")
    t = Table(title=f"{report.task}: [{colour}]{report.status}[/{colour}]", show_header=False)
    t.add_row("objects placed", f"{report.objects_done} / {report.objects_total}")
    t.add_row("attempts / recoveries", f"{report.attempts} / {report.recoveries}")
    t.add_row("perception", report.perception)
    if report.collisions is not None:
        t.add_row("collisions / limit violations", f"{report.collisions} / {report.limit_violations}")
    t.add_row("wall / compute time", f"{report.wall_time_s:.1f} s / {report.compute_time_s:.1f} s")
    if report.sim_time_s is not None:
        t.add_row("simulated time", f"{report.sim_time_s:.1f} s")
    slow = sorted(report.state_time_s.items(), key=lambda kv: -kv[1])[:4]
    t.add_row("time by state", ", ".join(f"{k} {v:.1f}s" for k, v in slow))
    if report.message:
        t.add_row("message", report.message)
    c.print(t)
