"""The on-robot daemon: a local HTTP API (FastAPI) over the task runner.

    app = create_app(config, token="...")          # uvicorn.run(app, host="127.0.0.1", port=8765)

- Bound to 127.0.0.1 by default (``kitchenbot daemon``). Everything that can move the robot (start a task,
  resume, home) and pause need the token: ``Authorization: Bearer <token>`` or ``X-Kitchenbot-Token``. The token
  comes from ``KITCHENBOT_TOKEN`` or a token file (created with mode 0600 when missing). ``POST /stop`` needs no
  token on purpose: stopping never moves anything, and whoever can reach the local port must be able to stop.
- One run at a time, in a worker thread; ``/stop`` acts at once (the arm decelerates), ``/pause`` and
  ``/resume`` at safe points. ``GET /events`` streams runner events as server-sent events.
- Malformed bodies, unknown tasks and missing tokens get 4xx with a message and never reach a driver.
- The journal is shared with ``kitchenbot run``: interrupted runs are reported at start-up and motion is refused
  until ``POST /home``.
"""

from __future__ import annotations

import io
import json
import os
import queue
import secrets
import threading
import time
from pathlib import Path
from typing import Literal

from fastapi import Depends, FastAPI, Header, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response, StreamingResponse
from pydantic import BaseModel, ConfigDict, Field

from kitchenbot.executive.journal import HomingRequired, Journal, default_journal_path
from kitchenbot.executive.machine import TERMINAL

TaskName = Literal["sink-pick", "sink-to-dishwasher", "cup-stacking"]


class StartRun(BaseModel):
    model_config = ConfigDict(extra="forbid")

    task: TaskName
    seed: int | None = Field(None, ge=0, description="simulated scene seed (simulation only)")
    oracle_perception: bool = Field(False, description="simulation only: poses from the simulator's truth")


def load_token(token_file: str | Path | None = None) -> str:
    """KITCHENBOT_TOKEN, else the token file (created with a random token, mode 0600, when missing)."""
    env = os.environ.get("KITCHENBOT_TOKEN")
    if env:
        return env
    path = Path(token_file) if token_file else default_journal_path(False).parent / "token"
    if path.exists():
        tok = path.read_text().strip()
        if not tok:
            raise ValueError(f"{path}: the token file is empty")
        return tok
    path.parent.mkdir(parents=True, exist_ok=True)
    tok = secrets.token_urlsafe(24)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(tok + "\n")
    return tok


class Daemon:
    """The run slot, the journal and the event fan-out shared by the endpoints."""

    def __init__(self, config, journal: Journal, runner_factory, home_action):
        self.config = config
        self.journal = journal
        self.runner_factory = runner_factory
        self.home_action = home_action
        self.lock = threading.Lock()
        self.runner = None
        self.thread: threading.Thread | None = None
        self.subscribers: list[queue.Queue] = []
        self.interrupted = [r.as_dict() for r in journal.recover()]
        self.last_error: str | None = None

    def publish(self, ev: dict) -> None:
        ev = {**ev, "wall_time": time.time()}
        for q in list(self.subscribers):
            try:
                q.put_nowait(ev)
            except queue.Full:
                pass

    @property
    def busy(self) -> bool:
        return self.thread is not None and self.thread.is_alive()

    def status(self) -> dict:
        r = self.runner
        out = {"busy": self.busy, "state": r.state if r is not None else "idle", "homed": self.journal.homed,
               "interrupted_runs": self.interrupted, "last_error": self.last_error}
        if r is not None:
            rep = r.report
            out.update(run_id=r.run_id, task=rep.task, status=rep.status, objects_done=rep.objects_done,
                       objects_total=rep.objects_total, attempts=rep.attempts, recoveries=rep.recoveries)
        return out

    def start(self, req: StartRun) -> dict:
        with self.lock:
            if self.busy:
                raise HTTPException(409, f"a run is in progress ({self.runner.report.task}, state "
                                         f"{self.runner.state}); stop it first")
            try:
                self.journal.require_homed()
            except HomingRequired as e:
                raise HTTPException(409, str(e)) from None
            try:
                runner = self.runner_factory(req.task, req.seed, req.oracle_perception)
            except ValueError as e:
                raise HTTPException(422, str(e)) from None
            runner.listeners.append(self.publish)
            self.runner = runner
            started = threading.Event()

            def work():
                try:
                    started.set()
                    runner.run()
                except Exception as e:  # noqa: BLE001 - reported through /status
                    self.last_error = f"{type(e).__name__}: {e}"
                    self.publish({"type": "error", "message": self.last_error})
                finally:
                    started.set()

            self.last_error = None
            self.thread = threading.Thread(target=work, name=f"run-{req.task}", daemon=True)
            self.thread.start()
            started.wait(5)
            return {"accepted": True, "task": req.task, "seed": runner.report.seed}


def create_app(config, *, token: str, journal: Journal | None = None, runner_factory=None, home_action=None,
               oracle_allowed: bool | None = None) -> FastAPI:
    """The daemon's FastAPI app. `runner_factory(task, seed, oracle) -> TaskRunner` and `home_action()` default to
    building from `config` (executive.session); tests inject their own."""
    from kitchenbot.executive.session import build_runner, is_simulated

    sim = is_simulated(config)
    journal = journal or Journal(default_journal_path(sim))
    if oracle_allowed is None:
        oracle_allowed = sim

    if runner_factory is None:
        def runner_factory(task, seed, oracle):
            if oracle and not oracle_allowed:
                raise ValueError("oracle_perception needs the simulated cell")
            return build_runner(config, task, seed, oracle_perception=oracle, journal=journal)

    if home_action is None:
        def home_action():
            from kitchenbot.executive.assembly import assemble
            from kitchenbot.executive.runner import home_arm
            from kitchenbot.planning.pick_place import Planner

            robot = assemble(config)
            home_arm(robot, Planner.from_config(config, robot.inventory), journal,
                     advance=robot.arm.step if sim else None)

    d = Daemon(config, journal, runner_factory, home_action)
    app = FastAPI(title="kitchenbot daemon", version="1",
                  description="Start, stop, pause and watch kitchenbot tasks on this robot. Moving the robot needs "
                              "the token (Authorization: Bearer ...).")
    app.state.daemon = d

    @app.exception_handler(RequestValidationError)
    async def _bad_body(request: Request, exc: RequestValidationError):
        msgs = []
        for e in exc.errors():
            loc = ".".join(str(x) for x in e.get("loc", ()) if x != "body") or "body"
            msgs.append(f"{loc}: {e.get('msg')}")
        return JSONResponse(status_code=422, content={"detail": "invalid request: " + "; ".join(msgs),
                                                      "errors": json.loads(json.dumps(exc.errors(), default=str))})

    def require_token(authorization: str | None = Header(None), x_kitchenbot_token: str | None = Header(None)):
        given = x_kitchenbot_token
        if authorization and authorization.lower().startswith("bearer "):
            given = authorization[7:].strip()
        if not given:
            raise HTTPException(401, "missing token: send 'Authorization: Bearer <token>' or 'X-Kitchenbot-Token'",
                                headers={"WWW-Authenticate": "Bearer"})
        if not secrets.compare_digest(given, token):
            raise HTTPException(403, "wrong token")

    @app.get("/status", summary="what the robot is doing")
    def status():
        return d.status()

    @app.post("/runs", status_code=202, dependencies=[Depends(require_token)], summary="start a task")
    def start(req: StartRun):
        return d.start(req)

    @app.post("/stop", summary="stop now (no token needed: stopping never moves the robot)")
    def stop():
        r = d.runner
        if r is None or r.state in TERMINAL:
            return {"stopped": False, "detail": "nothing is running"}
        r.request_stop()
        if d.thread is not None:
            d.thread.join(10)
        return {"stopped": True, "state": r.state}

    @app.post("/pause", dependencies=[Depends(require_token)], summary="pause at the next safe point")
    def pause():
        r = d.runner
        if not d.busy:
            raise HTTPException(409, "nothing is running")
        r.request_pause()
        return {"pausing": True, "state": r.state}

    @app.post("/resume", dependencies=[Depends(require_token)], summary="resume a paused run")
    def resume():
        r = d.runner
        if not d.busy:
            raise HTTPException(409, "nothing is running")
        r.request_resume()
        return {"resumed": True}

    @app.post("/home", dependencies=[Depends(require_token)], summary="move the arm home; clears the homing "
                                                                      "requirement after an interrupted run")
    def home():
        if d.busy:
            raise HTTPException(409, "a run is in progress; stop it first")
        from kitchenbot.drivers.errors import DriverError

        try:
            d.home_action()
        except DriverError as e:  # the arm could not be reached / moved: say so, stay un-homed
            raise HTTPException(503, f"homing failed: {type(e).__name__}: {e}") from None
        d.interrupted = []
        return {"homed": True}

    @app.get("/runs", summary="run history (newest first)")
    def runs(limit: int = 50):
        return [{k: v for k, v in r.as_dict().items() if k != "report"} | {"objects_done": (r.report or {}).get(
            "objects_done")} for r in journal.runs(limit=max(1, min(limit, 1000)))]

    @app.get("/runs/{run_id}", summary="one run: its report and journal")
    def run(run_id: int, events: bool = False):
        r = journal.run(run_id)
        if r is None:
            raise HTTPException(404, f"no run {run_id}")
        out = r.as_dict()
        if events:
            out["events"] = journal.events(run_id)
        return out

    @app.get("/images/latest", summary="names of the latest captured images")
    def images():
        r = d.runner
        return sorted(r.latest_images) if r is not None else []

    @app.get("/images/latest/{name}", summary="one latest image as PNG", response_class=Response,
             responses={200: {"content": {"image/png": {}}}})
    def image(name: str):
        from PIL import Image

        r = d.runner
        if r is None or name.removesuffix(".png") not in r.latest_images:
            raise HTTPException(404, f"no image {name!r}")
        buf = io.BytesIO()
        Image.fromarray(r.latest_images[name.removesuffix(".png")]).save(buf, format="PNG")
        return Response(buf.getvalue(), media_type="image/png")

    @app.get("/events", summary="live status stream (server-sent events)")
    def events(limit: int | None = None, heartbeat: float = 15.0):
        q: queue.Queue = queue.Queue(maxsize=1000)
        d.subscribers.append(q)

        def gen():
            n = 0
            try:
                yield f"event: status\ndata: {json.dumps(d.status(), default=str)}\n\n"
                while limit is None or n < limit:
                    try:
                        ev = q.get(timeout=heartbeat)
                    except queue.Empty:
                        yield ": keep-alive\n\n"
                        continue
                    n += 1
                    yield f"event: {ev.get('type', 'message')}\ndata: {json.dumps(ev, default=str)}\n\n"
            finally:
                d.subscribers.remove(q)

        return StreamingResponse(gen(), media_type="text/event-stream")

    return app
