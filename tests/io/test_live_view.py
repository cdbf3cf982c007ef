"""The live view driven by the simulator through the real gateway process, in a real
headless Chromium (Debian chromium, DevTools protocol).

`pfdoa sim --transport timed` (the real firmware core per anchor, a moving robot with
odometry) writes its timed stream into a pipe that this test holds; the test hands it on to
`pfdoa gateway --replay-capture - --web 127.0.0.1:0` in two portions and reads the page
after each: the page shows the site's anchors, the particle cloud and the estimate, and the
drawn estimate is the gateway's own output record at two moments, metres apart. Nothing is
timed: the gateway only gets the second portion after the page showed the first, and each
wait is for a state (with a hang guard).

Set PFDOA_UPDATE_SCREENSHOT=1 to copy the screenshot to docs/img/live-view.png.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pfdoa.site import load_site

REPO = Path(__file__).resolve().parents[2]
HANG_GUARD_S = 120.0
LINE_TIME = re.compile(r"\((\S+)\) ")

ESTIMATE = ("(() => { const g = document.getElementById('estimate'); return g.getAttribute('visibility') === "
            "'visible' ? [+g.dataset.x, +g.dataset.y, +g.dataset.n] : null; })()")


def wait_until(cond, what: str):
    deadline = time.monotonic() + HANG_GUARD_S
    while True:
        v = cond()
        if v:
            return v
        if time.monotonic() > deadline:
            raise TimeoutError(f"hang guard: no {what} after {HANG_GUARD_S:.0f} s")
        time.sleep(0.05)


class Relay:
    """Hands the simulator's stream on to the gateway, up to a stream time at a time."""

    def __init__(self, src, dst) -> None:
        self.src, self.dst = src, dst
        self.t = -math.inf
        self.lines = 0

    def until(self, t_end: float | None) -> None:
        for line in self.src:
            self.dst.write(line)
            self.lines += 1
            m = LINE_TIME.match(line)
            if m:
                self.t = float(m.group(1))
            if t_end is not None and self.t >= t_end:
                break
        self.dst.flush()


def records(path: Path) -> list[dict]:
    return [json.loads(s) for s in path.read_text().splitlines()] if path.exists() else []


def test_the_page_follows_the_simulator_through_the_gateway(browser, tmp_path):
    out = tmp_path / "sim"
    sim = subprocess.Popen([sys.executable, "-m", "pfdoa", "-q", "sim", "--scenario", "demo", "--transport", "timed",
                            "--odom", "--duration", "24", "--seed", "2", "--out-dir", str(out)],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    gw = None
    try:
        header = sim.stdout.readline()  # the site file is written before the stream starts
        assert header.startswith("# pfdoa capture"), header
        est, log = tmp_path / "est.jsonl", tmp_path / "gateway.log"
        with open(log, "w") as err:
            gw = subprocess.Popen([sys.executable, "-m", "pfdoa", "-q", "gateway", "--config", str(out / "site.toml"),
                                   "--replay-capture", "-", "--web", "127.0.0.1:0", "--health", "0", "--seed", "1",
                                   "--out", str(est)],
                                  stdin=subprocess.PIPE, stderr=err, stdout=subprocess.DEVNULL, text=True)
        gw.stdin.write(header)
        relay = Relay(sim.stdout, gw.stdin)
        relay.until(8.0)  # the first 8 s of the run
        url = wait_until(lambda: (re.findall(r"live view on (http://\S+)", log.read_text()) or [None])[0],
                         "'live view on' line from the gateway")
        browser.navigate(url)

        site = load_site(out / "site.toml")
        anchors = browser.wait_for(
            "(() => { const a = [...document.querySelectorAll('#anchors [data-anchor]')]; "
            "return a.length ? a.map(g => [+g.dataset.anchor, +g.dataset.x, +g.dataset.y]) : null; })()",
            "anchors drawn")
        assert anchors == [[a.id, a.x, a.y] for a in site.anchors]

        def moment(n_min: int) -> tuple[float, float, int]:
            x, y, n = browser.wait_for(f"(() => {{ const e = {ESTIMATE}; return e && e[2] >= {n_min} ? e : null; }})()",
                                       f"estimate number {n_min}")
            rec = wait_until(lambda: (records(est)[n - 1:n] or [None])[0], f"output record {n}")
            # The drawn estimate is the gateway's n-th output record (JSON: 4 decimals).
            assert (x, y) == pytest.approx((rec["x"], rec["y"]), abs=6e-5)
            return x, y, n

        x1, y1, n1 = moment(50)
        assert n1 < 100  # the gateway has not seen the second portion yet
        relay.until(20.0)
        x2, y2, n2 = moment(170)
        assert math.dist((x1, y1), (x2, y2)) > 1.0  # the robot moved metres, and so did the drawn estimate

        # Particles around the estimate, its ellipse, the track, and health from the sampler.
        count = browser.wait_for("+document.getElementById('particles').dataset.count", "particles drawn")
        assert 0 < count <= 200
        assert browser.eval("document.getElementById('ellipse').getAttribute('visibility')") == "visible"
        assert browser.eval("document.getElementById('track').getAttribute('points').split(' ').length") >= 170
        levels = browser.wait_for(
            "(() => { const s = window.pfdoaState; return s && s.health ? "
            "[...document.querySelectorAll('#anchors [data-anchor]')].map(g => g.dataset.level) : null; })()",
            "a health snapshot on the page")
        assert levels == ["OK"] * len(site.anchors)  # a fault-free run
        shot = tmp_path / "live-view.png"
        browser.screenshot(shot)
        assert shot.stat().st_size > 10_000
        if os.environ.get("PFDOA_UPDATE_SCREENSHOT"):
            shutil.copy(shot, REPO / "docs" / "img" / "live-view.png")

        relay.until(None)  # the rest; the end of the stream ends the gateway
        gw.stdin.close()
        assert gw.wait(timeout=HANG_GUARD_S) == 0, log.read_text()[-2000:]
        assert sim.wait(timeout=HANG_GUARD_S) == 0
        assert len(records(est)) > n2
    finally:
        for p in (gw, sim):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()

