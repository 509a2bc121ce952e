"""The operator page (executive/static) in a real browser: headless Chromium (the Debian package, installed by
scripts/setup.sh) driven by Playwright, against a daemon process on a small simulated cell
(operator_sim_daemon.py). Every wait is for a condition on the page or the API, with generous limits.

Set KITCHENBOT_SCREENSHOTS=DIR to save the screenshots of the main states (docs/operator_page_*.png).
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

CHROMIUM = os.environ.get("KITCHENBOT_CHROMIUM", "/usr/bin/chromium")
TOKEN = "operator-page-test-token"
WAIT_MS = 90_000  # generous: a loaded 2-core machine
SHOTS = os.environ.get("KITCHENBOT_SCREENSHOTS")
LAUNCHER = Path(__file__).with_name("operator_sim_daemon.py")


def _chromium() -> str:
    path = shutil.which(CHROMIUM) or (CHROMIUM if os.access(CHROMIUM, os.X_OK) else None)
    if path is None:
        pytest.fail(f"the browser tests need Chromium at {CHROMIUM} (Debian package `chromium`: scripts/setup.sh "
                    "installs it; or set KITCHENBOT_CHROMIUM)", pytrace=False)
    return path


class SimDaemon:
    """operator_sim_daemon.py as a child process (killable with SIGKILL, restartable on the same state)."""

    def __init__(self, state_dir: Path):
        self.state_dir = state_dir
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.url = f"http://127.0.0.1:{self.port}"
        self.proc: subprocess.Popen | None = None

    def start(self) -> None:
        env = {**os.environ, "KITCHENBOT_TOKEN": TOKEN, "KITCHENBOT_STATE_DIR": str(self.state_dir)}
        self.log = open(self.state_dir / f"daemon-{time.monotonic_ns()}.log", "w")
        self.proc = subprocess.Popen([sys.executable, str(LAUNCHER), str(self.port), str(self.state_dir)], env=env,
                                     stdout=self.log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + WAIT_MS / 1000
        while time.monotonic() < deadline:  # until it answers (or dies)
            if self.proc.poll() is not None:
                raise AssertionError(f"the daemon exited: {(self.state_dir / self.log.name).read_text()[-2000:]}")
            try:
                if httpx.get(self.url + "/status", timeout=5).status_code == 200:
                    return
            except httpx.TransportError:
                pass
            time.sleep(0.1)  # polling a condition with a deadline, not a synchronising sleep
        raise AssertionError("the daemon did not answer")

    def status(self) -> dict:
        return httpx.get(self.url + "/status", timeout=30).json()

    def kill9(self) -> None:
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(30)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(20)


@pytest.fixture
def daemon(tmp_path):
    d = SimDaemon(tmp_path)
    d.start()
    yield d
    d.stop()


@pytest.fixture
def browser():
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.fail("the browser tests need Playwright for Python: pip install -e '.[dev]'", pytrace=False)
    exe = _chromium()
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=exe, args=[
            "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run"])
        yield b
        b.close()


def shot(page, name: str) -> None:
    if SHOTS:
        page.wait_for_function("[...document.images].every(i => i.complete && i.naturalWidth > 0)")
        page.evaluate("window.scrollTo(0, 0)")
        Path(SHOTS).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(SHOTS) / f"operator_page_{name}.png"), full_page=True)


def open_page(browser, daemon, width=1024, height=768):
    from playwright.sync_api import expect

    expect.set_options(timeout=WAIT_MS)
    page = browser.new_page(viewport={"width": width, "height": height})
    page.set_default_timeout(WAIT_MS)
    page.goto(daemon.url + "/")
    expect(page.locator("#conn")).to_have_attribute("data-state", "open")
    return page


def test_a_run_with_the_token_progresses_stop_stops_it_and_a_wrong_token_is_refused(browser, daemon):
    from playwright.sync_api import expect

    page = open_page(browser, daemon)
    expect(page.locator("#state")).to_have_text("idle")
    expect(page.locator("#start")).to_be_disabled()
    expect(page.locator("#start-why")).to_have_text("no token")
    expect(page.locator("#stop")).to_be_enabled()  # STOP needs no token
    shot(page, "idle")

    # a wrong token: the daemon refuses, the page says so in the API's words, nothing starts
    page.fill("#token", "not-the-token")
    page.click("#token-save")
    expect(page.locator("#start")).to_be_enabled()
    page.click("#start")
    expect(page.locator("#api-error")).to_have_text("POST /runs: 403 wrong token")
    shot(page, "wrong_token")
    assert daemon.status()["state"] == "idle" and httpx.get(daemon.url + "/runs").json() == []

    # the token, kept in the tab's session storage; a run (held in execute by operator_sim_daemon.py) progresses
    # from scan to execute, with the cup's outline and the planned grasp drawn on the camera view
    page.fill("#token", TOKEN)
    page.click("#token-save")
    assert page.evaluate("sessionStorage.getItem('kitchenbot.token')") == TOKEN
    page.select_option("#task-select", "sink-pick")
    page.click("#start")
    expect(page.locator("#api-ok")).to_have_text("started run #1 (sink-pick)")
    expect(page.locator("#state")).to_have_attribute("data-state", "execute")
    expect(page.locator("#progress")).to_have_text("object 1 of 1 (cup) · 0 placed")
    expect(page.locator("#start-why")).to_have_text("busy: run #1 is execute")
    expect(page.locator("#pause")).to_be_enabled()
    expect(page.locator("#views svg polygon.selected")).to_have_count(1)  # the cup
    expect(page.locator("#views line.finger")).to_have_count(2)  # the grasp's finger pads
    shot(page, "running")

    # STOP (no token needed) stops it; the history shows the run's report
    page.click("#stop")
    expect(page.locator("#state")).to_have_attribute("data-state", "stopped")
    s = daemon.status()
    assert s["state"] == "stopped" and s["status"] == "stopped" and s["run_id"] == 1 and not s["busy"]
    expect(page.locator("#runs tr.run").first).to_contain_text("stopped on request")
    page.locator("#runs tr.run").first.click()
    expect(page.locator("#runs td.report")).to_contain_text("No failures")
    expect(page.locator("#start")).to_be_enabled()
    shot(page, "stopped")

    # space is STOP wherever the focus is: here on Start, which it must not press
    page.focus("#start")
    with page.expect_request(lambda r: r.method == "POST" and r.url.endswith("/stop")):
        page.keyboard.press("Space")
    expect(page.locator("#api-ok")).to_have_text("nothing is running")
    assert len(httpx.get(daemon.url + "/runs").json()) == 1


def test_the_homing_banner_appears_after_a_kill_9_and_clears_after_home(browser, daemon):
    from playwright.sync_api import expect

    page = open_page(browser, daemon, 390, 844)  # a phone
    page.fill("#token", TOKEN)
    page.click("#token-save")
    page.select_option("#task-select", "sink-pick")
    page.click("#start")
    expect(page.locator("#state")).to_have_attribute("data-state", "execute")
    expect(page.locator("#banner")).to_be_hidden()

    daemon.kill9()  # mid-run: the journal has a run without an end
    expect(page.locator("#conn")).to_have_attribute("data-state", "lost")
    expect(page.locator("#start-why")).to_have_text("no connection to the daemon")
    daemon.start()
    expect(page.locator("#conn")).to_have_attribute("data-state", "open")
    expect(page.locator("#banner")).to_be_visible()
    expect(page.locator("#banner-text")).to_contain_text("run 1 (sink-pick) was interrupted")
    expect(page.locator("#start-why")).to_have_text("homing required")
    assert page.evaluate("document.scrollingElement.scrollWidth <= window.innerWidth")  # no sideways scrolling
    shot(page, "homing_required_phone")
    page.set_viewport_size({"width": 1024, "height": 768})
    shot(page, "homing_required")

    page.click("#banner-home")
    expect(page.locator("#banner")).to_be_hidden()
    expect(page.locator("#api-ok")).to_have_text("homed: motion allowed again")
    expect(page.locator("#start")).to_be_enabled()
    s = daemon.status()
    assert s["homed"] and s["interrupted_runs"] == []
    page.locator("#runs tr.run").first.click()
    expect(page.locator("#runs td.report")).to_contain_text("Interrupted")
