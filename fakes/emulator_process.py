"""The test-side handle of a device emulator that runs in its own process (the Dynamixel servo, the UR controller).

The child takes one JSON request per line on its stdin and answers one JSON line on its stdout; its first line is a
hello. Its own process keeps a vendor library's blocking calls (which hold the GIL) from stalling the emulator.
"""

from __future__ import annotations

import json
import selectors
import subprocess
import sys


class EmulatorProcess:
    """Start, talk to and stop one emulator child process. Subclasses define `start()` with `_spawn`."""

    name = "emulator"
    proc: subprocess.Popen | None = None

    def _spawn(self, argv: list[str], timeout: float) -> dict | None:
        """Run `python -u *argv` and return its hello line, or None (stopped again) when it exited at start."""
        self.proc = subprocess.Popen([sys.executable, "-u", *argv], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     text=True, bufsize=1)
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        if not sel.select(timeout):
            self.stop()
            raise RuntimeError(f"{self.name} did not start within {timeout} s")
        line = self.proc.stdout.readline()
        if not line:
            self.stop()
            return None
        return json.loads(line)

    def _call(self, **msg) -> dict:
        if self.proc is None or self.proc.poll() is not None:
            raise RuntimeError(f"{self.name} is not running")
        self.proc.stdin.write(json.dumps(msg) + "\n")
        self.proc.stdin.flush()
        out = json.loads(self.proc.stdout.readline())
        if not out.get("ok"):
            raise ValueError(out.get("error"))
        return out

    def start(self, timeout: float = 10.0):
        raise NotImplementedError

    def stop(self) -> None:
        proc, self.proc = self.proc, None
        if proc is None:
            return
        for stream in (proc.stdin, proc.stdout):
            try:
                stream.close()
            except OSError:
                pass
        proc.terminate()
        try:
            proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=2.0)

    def __enter__(self):
        return self.start() if self.proc is None else self

    def __exit__(self, *exc) -> None:
        self.stop()

    def __del__(self) -> None:
        try:
            self.stop()
        except Exception:  # noqa: BLE001 - interpreter shutdown; the child exits on stdin EOF anyway
            pass
