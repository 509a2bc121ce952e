"""The on-robot daemon: a local HTTP API (FastAPI) over the task runner.

    app = create_app(config, token="...")          # uvicorn.run(app, host="127.0.0.1", port=8765)

- Bound to 127.0.0.1 by default (``kitchenbot daemon``). Everything that can move the robot (start a task,
  resume, home) and pause need the token: ``Authorization: Bearer <token>`` or ``X-Kitchenbot-Token``. The token
  comes from ``KITCHENBOT_TOKEN`` or a token file (created with mode 0600 when missing). ``POST /stop`` needs no
  token on purpose: stopping never moves anything, and whoever can reach the local port must be able to stop.
- One run at a time, in a worker thread; ``/stop`` acts at once (the arm decelerates), ``/pause`` and
  ``/resume`` at safe points. ``GET /events`` streams runner events as server-sent events.
- Malformed bodies, unknown tasks, numbers out of range and missing tokens get 4xx with a message (a 422 names
  the field and its range) and never reach a driver.
- ``POST /runs`` begins the run in the journal and answers with its id; a worker that dies leaves ``/status``
  and the journal saying the run failed, with the error (homing required: the arm's pose is unknown).
- ``GET /`` is the operator page (``static/``, docs/operator.md); ``GET /perception/latest`` gives it the
  perceived outlines and the chosen grasp in image coordinates (executive/scene_overlay.py).
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
from dataclasses import dataclass, field
from pathlib import Path as FilePath
from typing import Annotated, Literal

from fastapi import Depends, FastAPI, Header, HTTPException, Path, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field

from kitchenbot.executive.journal import HomingRequired, Journal, default_journal_path
from kitchenbot.executive.machine import TERMINAL
from kitchenbot.executive.scene_overlay import PerceptionTracker

TaskName = Literal["sink-pick", "sink-to-dishwasher", "cup-stacking"]

#: Largest simulated scene seed (numpy seeds any non-negative integer; the journal stores a 64-bit one).
MAX_SEED = 2**32 - 1
#: Largest run id a request may name (the journal's ids are SQLite 64-bit integers).
MAX_RUN_ID = 2**63 - 1
#: The operator page (plain HTML/CSS/JS, no build step): served at / and /static/.
STATIC_DIR = FilePath(__file__).parent / "static"


class StartRun(BaseModel):
    model_config = ConfigDict(extra="forbid")

    task: TaskName
    seed: int | None = Field(None, ge=0, le=MAX_SEED, description="simulated scene seed (simulation only)")
    oracle_perception: bool = Field(False, description="simulation only: poses from the simulator's truth")


def load_token(token_file: str | FilePath | None = None) -> str:
    """KITCHENBOT_TOKEN, else the token file (created with a random token, mode 0600, when missing)."""
    env = os.environ.get("KITCHENBOT_TOKEN")
    if env:
        return env
    path = FilePath(token_file) if token_file else default_journal_path(False).parent / "token"
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


@dataclass
class RunSlot:
    """The run the daemon started last: its runner, journal id, worker thread and how the worker ended."""

    runner: object
    run_id: int
    tracker: PerceptionTracker | None = None
    thread: threading.Thread | None = None
    ended: threading.Event = field(default_factory=threading.Event)  # set when the worker has finished
    error: str | None = None  # the worker died of this (the runner did not end the run itself)


class Daemon:
    """The run slot, the journal and the event fan-out shared by the endpoints."""

    def __init__(self, config, journal: Journal, runner_factory, home_action):
        self.config = config
        self.journal = journal
        self.runner_factory = runner_factory
        self.home_action = home_action
        self.lock = threading.Lock()
        self.slot: RunSlot | None = None
        self.subscribers: list[queue.Queue] = []
        self.interrupted = [r.as_dict() for r in journal.recover()]

    @property
    def runner(self):
        s = self.slot
        return s.runner if s is not None else None

    def publish(self, ev: dict) -> None:
        ev = {**ev, "wall_time": time.time()}
        for q in list(self.subscribers):
            try:
                q.put_nowait(ev)
            except queue.Full:
                pass

    def publish_status(self) -> None:
        self.publish({"type": "status", **self.status()})

    @property
    def busy(self) -> bool:
        s = self.slot
        return s is not None and not s.ended.is_set()

    def status(self) -> dict:
        s = self.slot
        out = {"busy": self.busy, "state": "idle", "homed": self.journal.homed, "interrupted_runs": self.interrupted,
               "last_error": s.error if s is not None else None}
        if s is not None:
            r, rep = s.runner, s.runner.report
            state = r.state
            if s.ended.is_set() and state not in TERMINAL:
                state = "failed"  # the worker died outside the state machine (last_error says how)
            out.update(state=state, run_id=s.run_id, task=rep.task, status=rep.status, message=rep.message,
                       objects_done=rep.objects_done, objects_total=rep.objects_total, attempts=rep.attempts,
                       recoveries=rep.recoveries)
        return out

    def start(self, req: StartRun) -> dict:
        from kitchenbot.drivers.errors import DriverError

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
            except DriverError as e:  # a device could not be reached: nothing started
                raise HTTPException(503, f"cannot start: {type(e).__name__}: {e}") from None
            if runner.journal is None:
                runner.journal = self.journal
            try:  # reserved here, so that the reply names it and a worker that dies still leaves it ended
                run_id = runner.journal.begin_run(runner.report.task, runner.report.seed)
            except HomingRequired as e:
                raise HTTPException(409, str(e)) from None
            runner.run_id = run_id
            tracker = PerceptionTracker(runner) if hasattr(runner, "robot") else None
            if tracker is not None:  # before publish: a page fetching on an event finds what the event announced
                runner.listeners.append(tracker.on_event)
            runner.listeners.append(self.publish)
            slot = RunSlot(runner, run_id, tracker)
            slot.thread = threading.Thread(target=self._work, args=(slot,), name=f"run-{run_id}", daemon=True)
            self.slot = slot
            slot.thread.start()
        self.publish_status()
        return {"accepted": True, "run_id": run_id, "task": req.task, "seed": runner.report.seed}

    def _work(self, slot: RunSlot) -> None:
        """The worker: run; whatever happens, leave the journal and /status saying how the run ended."""
        runner = slot.runner
        try:
            runner.run()
        except BaseException as e:  # noqa: BLE001 - reported through /status and the journal
            slot.error = f"{type(e).__name__}: {e}"
            rep = runner.report
            if rep.status == "running":
                rep.status = "failed"
            rep.message = rep.message or f"the run's worker died: {slot.error}"
            self.publish({"type": "error", "run_id": slot.run_id, "message": slot.error})
        finally:
            try:
                rec = runner.journal.run(slot.run_id)
                if rec is not None and rec.status == "running":  # the runner could not end it: the arm's pose
                    rep = runner.report                           # is unknown, so homing is required
                    rep.status = "failed" if rep.status == "running" else rep.status
                    runner.journal.end_run(slot.run_id, rep.status, rep.to_dict() | {"error": slot.error},
                                           safe=False)
            except Exception as e:  # noqa: BLE001 - the journal itself failed: say so
                slot.error = (slot.error + "; " if slot.error else "") + f"journal: {type(e).__name__}: {e}"
            slot.ended.set()
            self.publish_status()


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
                              "the token (Authorization: Bearer ...). The operator page is at /.")
    app.state.daemon = d

    @app.exception_handler(RequestValidationError)
    async def _bad_body(request: Request, exc: RequestValidationError):
        msgs = []
        for e in exc.errors():
            loc = ".".join(str(x) for x in e.get("loc", ()) if x not in ("body", "query", "path")) or "body"
            msg = f"{loc}: {e.get('msg')}"
            lo, hi = _bounds_of(request, tuple(e.get("loc", ())))
            if lo is not None or hi is not None:
                msg += f" (expected {'' if lo is None else f'{lo} <= '}{loc}{'' if hi is None else f' <= {hi}'})"
            msgs.append(msg)
        return JSONResponse(status_code=422, content={"detail": "invalid request: " + "; ".join(msgs),
                                                      "errors": json.loads(json.dumps(exc.errors(), default=str))})

    def require_token(authorization: str | None = Header(None), x_kitchenbot_token: str | None = Header(None)):
        given = x_kitchenbot_token
        if authorization and authorization.lower().startswith("bearer "):
            given = authorization[7:].strip()
        if not given:
            raise HTTPException(401, "missing token: send 'Authorization: Bearer <token>' or 'X-Kitchenbot-Token'",
                                headers={"WWW-Authenticate": "Bearer"})
        if not secrets.compare_digest(given.encode(), token.encode()):
            raise HTTPException(403, "wrong token")

    @app.get("/", include_in_schema=False)
    def page():
        return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-cache"})

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    @app.get("/status", summary="what the robot is doing")
    def status():
        return d.status()

    @app.post("/runs", status_code=202, dependencies=[Depends(require_token)],
              summary="start a task; returns its run id")
    def start(req: StartRun):
        return d.start(req)

    @app.post("/stop", summary="stop now (no token needed: stopping never moves the robot)")
    def stop():
        s = d.slot
        if s is None or s.runner.state in TERMINAL or s.ended.is_set():
            return {"stopped": False, "detail": "nothing is running"}
        s.runner.request_stop()
        s.ended.wait(10)
        return {"stopped": True, "state": s.runner.state, "run_id": s.run_id}

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
        from kitchenbot.drivers.errors import DriverError

        with d.lock:  # no run can start while the arm is being homed
            if d.busy:
                raise HTTPException(409, "a run is in progress; stop it first")
            try:
                d.home_action()
            except DriverError as e:  # the arm could not be reached / moved: say so, stay un-homed
                raise HTTPException(503, f"homing failed: {type(e).__name__}: {e}") from None
            d.interrupted = []
        d.publish_status()
        return {"homed": True}

    @app.get("/runs", summary="run history (newest first)")
    def runs(limit: Annotated[int, Query(ge=1, le=1000, description="newest runs to list")] = 50):
        out = []
        for r in journal.runs(limit=limit):
            rep = r.report or {}
            out.append({k: v for k, v in r.as_dict().items() if k != "report"}
                       | {"objects_done": rep.get("objects_done"), "objects_total": rep.get("objects_total"),
                          "message": rep.get("message"), "failures": len(rep.get("failures") or [])})
        return out

    @app.get("/runs/{run_id}", summary="one run: its report and journal")
    def run(run_id: Annotated[int, Path(ge=1, le=MAX_RUN_ID)], events: bool = False):
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
        r = d.runner
        if r is None or name.removesuffix(".png") not in r.latest_images:
            raise HTTPException(404, f"no image {name!r}")
        return _png(r.latest_images[name.removesuffix(".png")])

    @app.get("/perception/latest", summary="the latest perception: objects' outlines and the chosen grasp in "
                                           "image coordinates of the views they were found in")
    def perception():
        s = d.slot
        if s is None or s.tracker is None:
            return {"seq": 0, "sim_t": None, "views": [], "grasp": None, "run_id": None}
        return s.tracker.overlay() | {"run_id": s.run_id}

    @app.get("/perception/latest/{index}.png", summary="the image of one view of the latest perception",
             response_class=Response, responses={200: {"content": {"image/png": {}}}})
    def perception_image(index: Annotated[int, Path(ge=0, le=63)]):
        s = d.slot
        rgb = s.tracker.image(index) if s is not None and s.tracker is not None else None
        if rgb is None:
            raise HTTPException(404, f"no view {index} in the latest perception")
        return _png(rgb)

    @app.get("/events", summary="live status stream (server-sent events)")
    def events(limit: Annotated[int | None, Query(ge=1, le=1_000_000, description="events to send, then close")]
               = None,
               heartbeat: Annotated[float, Query(ge=0.5, le=300.0, allow_inf_nan=False,
                                                 description="seconds between keep-alive comments")] = 15.0):
        q: queue.Queue = queue.Queue(maxsize=1000)
        d.subscribers.append(q)

        def gen():
            n = 0
            try:
                # retry: a page reconnects within a second when the daemon comes back (after a crash)
                yield f"retry: 1000\nevent: status\ndata: {json.dumps(d.status(), default=str)}\n\n"
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

        return StreamingResponse(gen(), media_type="text/event-stream", headers={"Cache-Control": "no-cache"})

    return app


def _png(rgb) -> Response:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format="PNG", compress_level=1)
    return Response(buf.getvalue(), media_type="image/png", headers={"Cache-Control": "no-store"})


def _bounds_of(request: Request, loc: tuple) -> tuple[float | None, float | None]:
    """(lower, upper) bound of the request field at `loc` (from its Field/Query/Path metadata), for messages that
    say the range and not only the side that was crossed."""
    route = request.scope.get("route")
    dep = getattr(route, "dependant", None)
    if dep is None or len(loc) < 2:
        return None, None
    info = None
    if loc[0] == "body" and dep.body_params:
        model = dep.body_params[0].field_info.annotation
        fields = getattr(model, "model_fields", {})
        info = fields.get(loc[1])
    else:
        params = {"query": dep.query_params, "path": dep.path_params}.get(loc[0], [])
        info = next((p.field_info for p in params if p.name == loc[1]), None)
    lo = hi = None
    for m in getattr(info, "metadata", []):
        lo = getattr(m, "ge", getattr(m, "gt", lo))
        hi = getattr(m, "le", getattr(m, "lt", hi))
    return lo, hi
