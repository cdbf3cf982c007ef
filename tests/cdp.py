"""A headless Debian Chromium driven through the DevTools protocol (tests only).

Started with the flags that work on a closed network (no background connections, no
component updates) and a fresh profile; ``--remote-debugging-port=0`` lets Chromium pick
the port, which it writes to ``DevToolsActivePort`` in the profile. Every wait has a hang
guard and fails with what it was waiting for; nothing here measures time.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import time
import urllib.request
from pathlib import Path

import websocket

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-extensions", "--hide-scrollbars", "--mute-audio"]
HANG_GUARD_S = 90.0


def chromium_path() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        p = shutil.which(name)
        if p:
            return p
    return None


class Browser:
    def __init__(self, profile: Path, width: int = 1100, height: int = 720) -> None:
        exe = chromium_path()
        if exe is None:
            raise RuntimeError("no chromium: tools/bootstrap.sh test installs Debian's chromium")
        profile.mkdir(parents=True, exist_ok=True)
        self.log = open(profile / "chromium.log", "w")
        self.proc = subprocess.Popen(
            [exe, *FLAGS, f"--user-data-dir={profile}", "--remote-debugging-port=0",
             f"--window-size={width},{height}", "about:blank"],
            stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True)
        port_file = profile / "DevToolsActivePort"
        self._wait(lambda: port_file.exists() and port_file.read_text().strip(), "DevToolsActivePort",
                   check_proc=True)
        port = int(port_file.read_text().splitlines()[0])
        pages = self._wait(lambda: [t for t in self._targets(port) if t.get("type") == "page"], "a page target")
        self.ws = websocket.create_connection(pages[0]["webSocketDebuggerUrl"], timeout=HANG_GUARD_S,
                                              suppress_origin=True)
        self._id = 0

    def _wait(self, cond, what: str, check_proc: bool = False):
        deadline = time.monotonic() + HANG_GUARD_S
        while True:
            try:
                v = cond()
            except (OSError, ValueError):
                v = None
            if v:
                return v
            if check_proc and self.proc.poll() is not None:
                raise RuntimeError(f"chromium exited ({self.proc.returncode}) before {what}")
            if time.monotonic() > deadline:
                raise TimeoutError(f"hang guard: no {what} after {HANG_GUARD_S:.0f} s")
            time.sleep(0.05)

    @staticmethod
    def _targets(port: int) -> list[dict]:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=5) as r:
            return json.loads(r.read())

    def call(self, method: str, **params) -> dict:
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv())
            if msg.get("id") == self._id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})

    def navigate(self, url: str) -> None:
        self.call("Page.enable")
        self.call("Page.navigate", url=url)

    def eval(self, expression: str):
        r = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"{expression}: {r['exceptionDetails'].get('text')}")
        return r["result"].get("value")

    def wait_for(self, expression: str, what: str | None = None):
        """The value of ``expression`` once it is truthy (hang guard: HANG_GUARD_S)."""
        return self._wait(lambda: self.eval(expression), what or expression)

    def screenshot(self, path: Path) -> None:
        data = self.call("Page.captureScreenshot", format="png")["data"]
        path.write_bytes(base64.b64decode(data))

    def close(self) -> None:
        try:
            self.ws.close()
        except (OSError, websocket.WebSocketException):
            pass
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, 15)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, 9)
                self.proc.wait()
        self.log.close()
