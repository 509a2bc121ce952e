"""The daemon's HTTP API through FastAPI's TestClient (no network): tokens, validation, start/stop/pause,
history, images, the event stream, and the homing interlock. Oracle perception in the simulated cell."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient

from kitchenbot.executive.daemon import create_app, load_token
from kitchenbot.executive.journal import Journal

TOKEN = "s3cret-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture
def app(make_runner, small_config, tmp_path):
    journal = Journal(tmp_path / "journal.sqlite")
    made = []

    def factory(task, seed, oracle):
        runner, world = make_runner(task=task, journal=False)
        runner.journal = journal
        made.append((runner, world))
        return runner

    homed = []
    app = create_app(small_config(), token=TOKEN, journal=journal, runner_factory=factory,
                     home_action=lambda: (homed.append(1), journal.mark_homed()))
    app.state.made, app.state.homed = made, homed
    return app


def wait_idle(client, timeout=60):
    t0 = time.time()
    while time.time() - t0 < timeout:
        s = client.get("/status").json()
        if not s["busy"]:
            return s
        time.sleep(0.05)
    raise AssertionError("run did not finish")


def test_moving_endpoints_need_the_token_and_bad_input_moves_nothing(app):
    c = TestClient(app)
    assert c.post("/runs", json={"task": "cup-stacking"}).status_code == 401
    assert c.post("/runs", json={"task": "cup-stacking"}, headers={"Authorization": "Bearer nope"}).status_code == 403
    assert c.post("/home").status_code == 401 and c.post("/pause").status_code == 401
    r = c.post("/runs", json={"task": "juggle"}, headers=AUTH)
    assert r.status_code == 422 and "task" in r.json()["detail"]
    r = c.post("/runs", content=b"{not json", headers={**AUTH, "content-type": "application/json"})
    assert r.status_code == 422 and "invalid request" in r.json()["detail"]
    r = c.post("/runs", json={"task": "cup-stacking", "speed": 9}, headers=AUTH)
    assert r.status_code == 422 and "speed" in r.json()["detail"]
    assert app.state.made == []  # nothing was built, nothing moved
    assert c.post("/pause", headers=AUTH).status_code == 409
    assert c.get("/status").json()["state"] == "idle"


def test_start_run_history_images_and_openapi(app):
    c = TestClient(app)
    r = c.post("/runs", json={"task": "cup-stacking", "seed": 0}, headers={"X-Kitchenbot-Token": TOKEN})
    assert r.status_code == 202, r.text
    assert c.post("/runs", json={"task": "cup-stacking"}, headers=AUTH).status_code in (202, 409)
    s = wait_idle(c)
    assert s["status"] == "succeeded" and s["objects_done"] == 1
    runs = c.get("/runs").json()
    assert runs[0]["task"] == "cup-stacking" and runs[0]["status"] == "succeeded"
    one = c.get(f"/runs/{runs[0]['id']}?events=true").json()
    assert one["report"]["objects_done"] == 1 and any(e["kind"] == "transition" for e in one["events"])
    assert c.get("/runs/99999").status_code == 404
    names = c.get("/images/latest").json()
    assert names
    img = c.get(f"/images/latest/{names[0]}.png")
    assert img.status_code == 200 and img.content[:8] == b"\x89PNG\r\n\x1a\n"
    spec = c.get("/openapi.json").json()
    assert {"/runs", "/stop", "/pause", "/resume", "/status", "/events", "/home"} <= set(spec["paths"])


def test_stop_pause_resume_and_event_stream(app):
    c = TestClient(app)
    # pause before the first safe point, watch the stream, resume, then stop
    assert c.post("/runs", json={"task": "cup-stacking"}, headers=AUTH).status_code == 202
    runner, world = app.state.made[-1]
    assert c.post("/pause", headers=AUTH).status_code == 200
    t0 = time.time()
    while runner.state != "paused" and time.time() - t0 < 30:
        time.sleep(0.02)
    assert runner.state == "paused"
    with c.stream("GET", "/events?limit=2") as s:
        assert c.post("/resume", headers=AUTH).status_code == 200
        lines = [ln for ln in s.iter_lines() if ln.startswith("data: ")]
    evs = [json.loads(ln[6:]) for ln in lines]
    assert evs[0]["state"] in ("paused", "scan") and evs[1]["type"] == "transition"
    r = c.post("/stop")  # no token needed to stop
    assert r.status_code == 200
    s = wait_idle(c)
    assert s["state"] in ("stopped", "done")
    assert not runner.arm.is_moving()


def test_interrupted_run_refuses_motion_until_home(app, tmp_path):
    journal = app.state.daemon.journal
    rid = journal.begin_run("sink-pick", 1)  # as if a previous daemon died mid-run
    c = TestClient(app)
    r = c.post("/runs", json={"task": "cup-stacking"}, headers=AUTH)
    assert r.status_code == 409 and "running" in r.json()["detail"]
    journal.recover()
    r = c.post("/runs", json={"task": "cup-stacking"}, headers=AUTH)
    assert r.status_code == 409 and "homed" in r.json()["detail"]
    assert app.state.made == []
    assert c.post("/home", headers=AUTH).json() == {"homed": True} and app.state.homed == [1]
    assert journal.run(rid).status == "interrupted"
    assert c.post("/runs", json={"task": "cup-stacking"}, headers=AUTH).status_code == 202
    wait_idle(c)


def test_token_sources(tmp_path, monkeypatch):
    monkeypatch.delenv("KITCHENBOT_TOKEN", raising=False)
    f = tmp_path / "tok"
    t1 = load_token(f)
    assert len(t1) > 20 and (f.stat().st_mode & 0o777) == 0o600 and load_token(f) == t1
    monkeypatch.setenv("KITCHENBOT_TOKEN", "from-env")
    assert load_token(f) == "from-env"
    monkeypatch.delenv("KITCHENBOT_TOKEN")
    f.write_text("  \n")
    with pytest.raises(ValueError, match="empty"):
        load_token(f)


def test_home_failure_is_a_503_and_stays_unhomed(make_runner, small_config, tmp_path):
    from kitchenbot.drivers.errors import DeviceNotConnectedError

    journal = Journal(tmp_path / "j.sqlite")
    journal.begin_run("sink-pick", 0)  # the daemon finds it interrupted at start-up

    def broken_home():
        raise DeviceNotConnectedError("arm: no answer from 192.168.1.10")

    app = create_app(small_config(), token=TOKEN, journal=journal, runner_factory=lambda *a: None,
                     home_action=broken_home)
    c = TestClient(app)
    r = c.post("/home", headers=AUTH)
    assert r.status_code == 503 and "no answer" in r.json()["detail"]
    assert not journal.homed and c.get("/status").json()["interrupted_runs"]


# ---- issue 15 item 4: every number bounded, the run id returned, a dying worker leaves /status consistent -------
@pytest.mark.parametrize("method, url, body, field, expect", [
    ("post", "/runs", {"task": "cup-stacking", "seed": 10**30}, "seed", "0 <= seed <= 4294967295"),
    ("post", "/runs", {"task": "cup-stacking", "seed": -1}, "seed", "0 <= seed <= 4294967295"),
    ("get", "/runs?limit=0", None, "limit", "1 <= limit <= 1000"),
    ("get", f"/runs?limit={10**30}", None, "limit", "1 <= limit <= 1000"),
    ("get", f"/runs/{10**30}", None, "run_id", "1 <= run_id <= 9223372036854775807"),
    ("get", "/runs/0", None, "run_id", "1 <= run_id <= 9223372036854775807"),
    ("get", "/events?heartbeat=0", None, "heartbeat", "0.5 <= heartbeat <= 300.0"),
    ("get", "/events?heartbeat=1e9", None, "heartbeat", "0.5 <= heartbeat <= 300.0"),
    ("get", "/events?heartbeat=nan", None, "heartbeat", "0.5 <= heartbeat <= 300.0"),
    ("get", "/events?limit=-3", None, "limit", "1 <= limit <= 1000000"),
    ("get", "/perception/latest/99999999999999999999.png", None, "index", "0 <= index <= 63"),
])
def test_numbers_out_of_range_are_a_422_naming_the_field_and_its_range(app, method, url, body, field, expect):
    c = TestClient(app)
    r = getattr(c, method)(url, headers=AUTH, **({"json": body} if body is not None else {}))
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert detail.startswith(f"invalid request: {field}: ") and f"(expected {expect})" in detail, detail
    assert app.state.made == [] and c.get("/status").json()["state"] == "idle"


def test_start_answers_with_the_run_id(app):
    c = TestClient(app)
    r = c.post("/runs", json={"task": "cup-stacking", "seed": 4294967295}, headers=AUTH)
    assert r.status_code == 202, r.text  # the largest seed is accepted (this test's factory builds its own scene)
    rid = r.json()["run_id"]
    journal = app.state.daemon.journal
    assert isinstance(rid, int) and journal.runs(limit=1)[0].id == rid
    assert c.get("/status").json()["run_id"] == rid
    assert app.state.daemon.slot.ended.wait(120)
    s = c.get("/status").json()
    assert s["run_id"] == rid and s["status"] == "succeeded" and not s["busy"]
    assert [x.id for x in journal.runs()] == [rid]  # one journal row per run: the runner used the reserved one
    assert c.get(f"/runs/{rid}").json()["report"]["run_id"] == rid


def test_a_worker_that_dies_leaves_status_failed_with_the_run_id_and_the_error(app):
    c = TestClient(app)
    d = app.state.daemon
    orig = d.runner_factory

    def dying(*a):
        runner = orig(*a)

        def truth(phase):  # raised inside TaskRunner.run() but outside its own error handling
            raise OverflowError("Python int too large to convert to SQLite INTEGER")

        runner.truth = truth
        return runner

    d.runner_factory = dying
    r = c.post("/runs", json={"task": "cup-stacking"}, headers=AUTH)
    assert r.status_code == 202, r.text
    rid = r.json()["run_id"]
    assert d.slot.ended.wait(60)
    s = c.get("/status").json()
    assert not s["busy"] and s["state"] == "failed" and s["status"] == "failed" and s["run_id"] == rid
    assert s["last_error"] == "OverflowError: Python int too large to convert to SQLite INTEGER"
    rec = d.journal.run(rid)
    assert rec.status == "failed" and rec.ended is not None and "OverflowError" in rec.report["error"]
    # where the arm is after a worker died is not known: the next run needs homing first
    assert not s["homed"]
    r = c.post("/runs", json={"task": "cup-stacking"}, headers=AUTH)
    assert r.status_code == 409 and "homed" in r.json()["detail"]
    assert c.post("/home", headers=AUTH).json() == {"homed": True}
    d.runner_factory = orig
    r = c.post("/runs", json={"task": "cup-stacking"}, headers=AUTH)
    assert r.status_code == 202 and r.json()["run_id"] == rid + 1
    assert d.slot.ended.wait(120) and c.get("/status").json()["status"] == "succeeded"


def test_latest_perception_outlines_and_grasp_are_in_image_coordinates(app):
    from kitchenbot.executive.scene_overlay import project

    c = TestClient(app)
    assert c.get("/perception/latest").json()["views"] == []
    assert c.get("/perception/latest/0.png").status_code == 404
    d = app.state.daemon
    seen = []  # the overlay as the page would have fetched it once the pick was planned
    orig = d.runner_factory

    def factory(*a):
        runner = orig(*a)
        runner.listeners.append(lambda ev: ev.get("trigger") == "executed" and seen.append(
            (d.slot.tracker.overlay(), d.slot.tracker.latest)))
        return runner

    d.runner_factory = factory
    assert c.post("/runs", json={"task": "cup-stacking"}, headers=AUTH).status_code == 202
    assert d.slot.ended.wait(120) and seen
    p, latest = seen[0]
    v = p["views"][0]
    cups = [o for o in v["objects"] if o["cls"] == "cup"]
    assert cups and [o["selected"] for o in cups] == [True] and p["grasp"]["cls"] == "cup"
    xy = np.array(cups[0]["outline"])
    assert len(xy) >= 3 and (xy >= 0).all() and (xy[:, 0] <= v["width"]).all() and (xy[:, 1] <= v["height"]).all()
    # the outline surrounds the projection of the cup's origin; the grasp's TCP is on the cup (a rim grasp)
    pose = next(q for q in latest.poses if q.cls == "cup")
    (x, y), = project(pose.T_base_obj[:3, 3][None], latest.views[0])
    assert xy[:, 0].min() <= x <= xy[:, 0].max() and xy[:, 1].min() <= y <= xy[:, 1].max()
    gx, gy = v["grasp"]["tcp"]
    assert xy[:, 0].min() - 10 <= gx <= xy[:, 0].max() + 10 and xy[:, 1].min() - 10 <= gy <= xy[:, 1].max() + 10
    assert len(v["grasp"]["fingers"]) == 2
    # after the run: the last perception (the verifying scan) and its image
    assert c.get("/perception/latest").json()["seq"] >= 2
    img = c.get("/perception/latest/0.png")
    assert img.status_code == 200 and img.content[:8] == b"\x89PNG\r\n\x1a\n"
