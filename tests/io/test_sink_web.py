"""Live view (pfdoa.sinks.web): address parsing, the HTTP endpoints, bounded clients, and
the page in a real headless Chromium (Debian chromium, DevTools protocol): it shows the
anchors and their health, and the drawn estimate moves as records are fed.

Set PFDOA_UPDATE_SCREENSHOT=1 to copy the test's screenshot to docs/img/live-view.png."""

from __future__ import annotations

import http.client
import json
import math
import socket
import time
import urllib.error
import urllib.request
from dataclasses import replace

import numpy as np
import pytest

from pfdoa.errors import InputError
from pfdoa.sinks.web import MAX_PARTICLES, WebSink, parse_address

from sink_feed import SITE, scripted_run, track


def get(url: str):
    with urllib.request.urlopen(url, timeout=30) as r:
        return r.status, r.headers.get("Content-Type"), r.read()


@pytest.mark.parametrize("spec,expected", [
    ("8080", ("127.0.0.1", 8080)), ("0", ("127.0.0.1", 0)), ("0.0.0.0:80", ("0.0.0.0", 80)),
    ("localhost:9000", ("localhost", 9000)), ("[::1]:8080", ("::1", 8080)),
])
def test_parse_address(spec, expected):
    assert parse_address(spec) == expected


@pytest.mark.parametrize("spec,msg", [
    ("", "port must be a number"), ("http", "port must be a number"), ("1.2.3.4:", "port must be a number"),
    ("70000", "0..65535"), (":8080", "empty host"), ("::1:8080", "in brackets"), ("[::1]8080", "expected"),
])
def test_parse_address_errors_name_the_option(spec, msg):
    with pytest.raises(InputError, match=f"--web .*{msg}"):
        parse_address(spec)


@pytest.fixture()
def run():
    return scripted_run()


def cloud(centre, n=500, seed=0):
    rng = np.random.default_rng(seed)
    return np.asarray(centre) + 0.3 * rng.standard_normal((n, 2))


def test_endpoints_serve_the_page_and_the_latest_state(run):
    holder = {"p": cloud((1, 1))}
    with WebSink("127.0.0.1:0", SITE, particles=lambda: holder["p"]) as sink:
        assert sink.url.startswith("http://127.0.0.1:") and sink.port > 0
        status, ctype, body = get(sink.url)
        assert status == 200 and ctype.startswith("text/html") and b"pfdoa live view" in body
        s = json.loads(get(sink.url + "state.json")[2])
        assert s["estimate"] is None and s["records"] == 0
        assert [a["id"] for a in s["site"]["anchors"]] == [0, 1, 2, 3]
        for rec in run.records[:5]:
            sink.write(rec)
        sink.health(run.snapshots[1][0])
        s = json.loads(get(sink.url + "state.json")[2])
        last = run.records[4]
        assert (s["estimate"]["x"], s["estimate"]["y"]) == (round(last.x, 6), round(last.y, 6))
        assert s["estimate"]["cov"] == [round(v, 8) for v in last.cov] and s["records"] == 5
        assert s["track"] == [[round(r.x, 4), round(r.y, 4)] for r in run.records[:5]]
        assert len(s["particles"]) == MAX_PARTICLES  # 500 thinned to at most 200
        assert s["health"]["anchors"]["3"]["level"] == "STALE" and s["health"]["line"] == run.snapshots[1][1]
        with pytest.raises(urllib.error.HTTPError) as exc:
            get(sink.url + "nope")
        assert exc.value.code == 404
        assert s["site"]["bounds"] == list(SITE.bounds)


def test_the_floor_plan_covers_the_sites_area():
    x0, y0, x1, y1 = SITE.bounds
    site = replace(SITE, area=(x0 - 2.0, y0, x1, y1 + 3.0))
    with WebSink("127.0.0.1:0", site) as sink:
        s = json.loads(get(sink.url + "state.json")[2])
    assert s["site"]["bounds"] == [x0 - 2.0, y0, x1, y1 + 3.0]


def test_track_is_bounded_and_a_failing_particle_source_is_ignored(run):
    def broken():
        raise RuntimeError("estimator busy")

    with WebSink("0", SITE, particles=broken, track=10) as sink:
        for k in range(50):
            sink.write(replace(run.records[k % len(run.records)], x=float(k), y=1.0))
        s = sink.state()
        assert [p[0] for p in s["track"]] == [float(k) for k in range(40, 50)]
        assert s["particles"] == [] and sink._particle_errors == 50


def get_when_served(url: str, guard_s: float = 60.0):
    """GET ``url``, retrying while the server turns connections away (hang guard)."""
    deadline = time.monotonic() + guard_s
    while True:
        try:
            return json.loads(get(url)[2])
        except (urllib.error.URLError, ConnectionError, http.client.HTTPException):
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def test_stuck_clients_are_bounded_and_do_not_block_writes(run):
    """Connections that send nothing: at most max_clients are served at once, each new one
    takes the place of the one that has waited longest (the stuck ones go, counted), the
    pipeline never waits on a socket, and a real client is served at once."""
    with WebSink("0", SITE, max_clients=2, header_timeout_s=120.0) as sink:
        stuck = [socket.create_connection((sink.host, sink.port)) for _ in range(6)]  # send nothing
        try:
            for rec in run.records:  # the pipeline side never waits on a socket
                sink.write(rec)
            assert sink.state()["records"] == len(run.records)
            for c in stuck[:4]:  # the four oldest were shut, each for a newer one
                c.settimeout(60.0)  # hang guard
                assert c.recv(1) == b""
            assert sink.evicted == 4 and sink.rejected == 0
            assert json.loads(get(sink.url + "state.json")[2])["records"] == len(run.records)
            assert sink.evicted == 5 and len(sink._server.conns) <= 2
        finally:
            for c in stuck:
                c.close()


class Trickler:
    """A client that sends a request one byte at a time, never finishing it, and connects
    again when the server shuts it (``again``); or, with ``reads=False``, asks for the page
    over and over and never reads an answer."""

    def __init__(self, sink: WebSink, reads: bool = True, again: bool = False) -> None:
        import threading

        self.addr = (sink.host, sink.port)
        self.sock = self._connect()
        self.stop = threading.Event()
        self.reads, self.again = reads, again
        self.connects = 1
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _connect(self) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # before connecting: a small window
        sock.connect(self.addr)
        return sock

    @property
    def local(self):
        return self.sock.getsockname()

    def _run(self) -> None:
        data = b"GET /state.json HTTP/1.1\r\nHost: x\r\nX-Slow: " if self.reads else \
            b"GET / HTTP/1.1\r\nHost: x\r\n\r\n" * 2000
        while not self.stop.is_set():
            try:
                if self.reads:
                    i = 0
                    while not self.stop.wait(0.02):  # a byte every 20 ms, never the end of the headers
                        self.sock.send(data[i % len(data):i % len(data) + 1])
                        i += 1
                else:
                    self.sock.sendall(data)  # never reads: the server's answers pile up until it blocks
                    self.stop.wait()
            except OSError:
                pass
            if not self.again or self.stop.is_set():
                return
            try:
                self.sock = self._connect()
                self.connects += 1
            except OSError:
                return

    def shut_by_server(self, timeout_s: float = 60.0) -> bool:
        """Wait (a hang guard) until the server has closed the connection."""
        self.sock.settimeout(timeout_s)
        try:
            while True:
                if self.reads:
                    return self.sock.recv(1) == b""
                if not self.sock.recv(65536):
                    return True
        except OSError:
            return True

    def close(self) -> None:
        self.stop.set()
        self.sock.close()
        self.thread.join(5)


def test_eight_slow_clients_never_keep_the_page_from_a_real_one(run):
    """Eight clients trickling their requests a byte at a time, connecting again whenever
    they are shut, hold every place: a real client is still served (the page and the
    state), each time it comes, by taking the place of the one that waited longest."""
    with WebSink("0", SITE, header_timeout_s=120.0, write_timeout_s=120.0) as sink:
        sink.write(run.records[0])
        slow = [Trickler(sink, again=True) for _ in range(8)]
        try:
            def held() -> bool:  # every place held by a trickler's current connection
                def addr(f):
                    try:
                        return f()
                    except OSError:  # shut meanwhile
                        return None

                with sink._server.conns_lock:
                    peers = {addr(c.getpeername) for c in sink._server.conns}
                return len(peers - {None}) == 8 and all(addr(lambda t=t: t.local) in peers for t in slow)

            for k in range(5):
                deadline = time.monotonic() + 60  # hang guard: every place taken again
                while not held() and time.monotonic() < deadline:
                    time.sleep(0.01)
                assert held()
                evicted = sink.evicted
                if k % 2:
                    status, _ctype, body = get(sink.url)
                    assert status == 200 and b"pfdoa live view" in body
                else:
                    assert json.loads(get(sink.url + "state.json")[2])["records"] == 1
                assert sink.evicted == evicted + 1  # a trickler made room
            assert sink.rejected == 0 and sum(t.connects for t in slow) >= 8 + 5 - 1
        finally:
            for t in slow:
                t.close()


def test_deadlines_shut_a_trickling_request_and_a_client_that_never_reads(run):
    """On the injected clock: a request still incomplete header_timeout_s after it began is
    shut, however steadily its bytes trickle; a response not written within write_timeout_s
    (the client reads nothing) is shut too; each counted, the places come free."""
    now = [0.0]
    with WebSink("0", SITE, max_clients=2, header_timeout_s=5.0, write_timeout_s=5.0,
                 clock=lambda: now[0]) as sink:
        slow, deaf = Trickler(sink), Trickler(sink, reads=False)
        try:
            # Until the deaf one's answers have filled the socket buffers (the server's write
            # blocks: no more requests served); a hang guard bounds the wait.
            deadline, seen, since = time.monotonic() + 60, -1, time.monotonic()
            while time.monotonic() < deadline and (sink.requests != seen or time.monotonic() - since < 1.0):
                if sink.requests != seen:
                    seen, since = sink.requests, time.monotonic()
                time.sleep(0.02)
            assert 0 < sink.requests < 2000 and sink.timed_out == 0 and len(sink._server.conns) == 2
            now[0] = 4.9  # not yet
            time.sleep(0.5)
            assert sink.timed_out == 0
            now[0] = 5.0  # both deadlines passed (the trickler has sent bytes all along)
            assert slow.shut_by_server() and deaf.shut_by_server()
            assert sink.timed_out == 2 and sink.evicted == 0
            sink.write(run.records[0])
            assert json.loads(get(sink.url + "state.json")[2])["records"] == 1
        finally:
            slow.close()
            deaf.close()


def test_a_place_still_being_freed_is_waited_for_not_refused(run, monkeypatch):
    """A connection shut for its deadline holds its place until its thread returns; a new
    client arriving in between (a busy machine) is served once that place is free, not
    refused because no one was left to evict."""
    import threading

    from pfdoa.sinks import web

    class Slots:  # the server's places, telling when a new connection found them all taken
        def __init__(self, sem):
            self.sem, self.full = sem, threading.Event()

        def acquire(self, *args, **kwargs):
            ok = self.sem.acquire(*args, **kwargs)
            if not ok:
                self.full.set()
            return ok

        def release(self):
            self.sem.release()

    ending, finishing = threading.Event(), threading.Event()
    finish = web._Handler.finish

    def held_finish(self):  # the shut connection's thread, held before it gives back its place
        finishing.set()
        ending.wait(60.0)  # hang guard
        finish(self)

    monkeypatch.setattr(web._Handler, "finish", held_finish)
    now = [0.0]
    with WebSink("0", SITE, max_clients=1, header_timeout_s=5.0, clock=lambda: now[0]) as sink:
        slots = sink._server.slots = Slots(sink._server.slots)
        idle = socket.create_connection((sink.host, sink.port))
        got, failed = {}, []

        def client():
            try:
                got.update(json.loads(get(sink.url + "state.json")[2]))
            except Exception as e:  # noqa: BLE001 - reported by the assertion below
                failed.append(e)

        try:
            idle.settimeout(60.0)  # hang guard
            deadline = time.monotonic() + 60  # hang guard: until the server has taken it
            while not sink._server.conns and time.monotonic() < deadline:
                time.sleep(0.01)
            now[0] = 5.0
            assert idle.recv(1) == b"" and finishing.wait(60.0)  # shut; its thread not yet ended
            assert sink.timed_out == 1 and not sink._server.conns
            monkeypatch.setattr(web._Handler, "finish", finish)
            sink.write(run.records[0])
            asker = threading.Thread(target=client, daemon=True)
            asker.start()
            assert slots.full.wait(60.0)  # it arrived while the shut thread still held the place
            ending.set()
            asker.join(60.0)
            assert not failed and got.get("records") == 1
            assert sink.rejected == 0 and sink.evicted == 0
        finally:
            ending.set()
            idle.close()


def test_an_idle_client_is_dropped_after_the_timeout(run):
    with WebSink("0", SITE, max_clients=1, header_timeout_s=0.3) as sink:
        idle = socket.create_connection((sink.host, sink.port))
        try:
            idle.settimeout(60.0)  # hang guard
            assert idle.recv(1) == b""  # the server closed it: it sent nothing for header_timeout_s
            sink.write(run.records[0])
            assert get_when_served(sink.url + "state.json")["records"] == 1
        finally:
            idle.close()


def test_listen_failure_is_an_input_error():
    with WebSink("0", SITE) as a:
        with pytest.raises(InputError, match="cannot listen"):
            WebSink(f"127.0.0.1:{a.port}", SITE)


# -- the page in a real browser ---------------------------------------------------------

ESTIMATE = "(() => { const g = document.getElementById('estimate'); " \
           "return g.getAttribute('visibility') === 'visible' ? " \
           "[+g.dataset.x, +g.dataset.y, +g.dataset.n] : null; })()"


def test_page_shows_anchors_and_the_estimate_moves_as_fed(browser, run, tmp_path):
    particles = {"p": None}
    with WebSink("127.0.0.1:0", SITE, particles=lambda: particles["p"]) as sink:
        browser.navigate(sink.url)
        anchors = browser.wait_for(
            "(() => { const a = [...document.querySelectorAll('#anchors [data-anchor]')]; "
            "return a.length ? a.map(g => [+g.dataset.anchor, +g.dataset.x, +g.dataset.y]) : null; })()",
            "anchors drawn")
        assert anchors == [[a.id, a.x, a.y] for a in SITE.anchors]
        assert browser.eval("document.getElementById('estimate').getAttribute('visibility')") == "hidden"

        # First moment: 10 records of the scripted track, particles around the last one.
        for k, rec in enumerate(run.records[:10]):
            particles["p"] = cloud(track(k), seed=k)
            sink.write(rec)
        sink.health(run.snapshots[0][0])
        first = browser.wait_for(f"(() => {{ const e = {ESTIMATE}; return e && e[2] === 10 ? e : null; }})()",
                                 "estimate of record 10")
        assert first[:2] == pytest.approx([run.records[9].x, run.records[9].y], abs=1e-6)

        # Second moment: 20 more records; health with anchor 2 rebooted and anchor 3 stale.
        for k, rec in enumerate(run.records[10:30], start=10):
            particles["p"] = cloud(track(k), seed=k)
            sink.write(rec)
        sink.health(run.snapshots[1][0])
        second = browser.wait_for(f"(() => {{ const e = {ESTIMATE}; return e && e[2] === 30 ? e : null; }})()",
                                  "estimate of record 30")
        last = run.records[29]
        assert second[:2] == pytest.approx([last.x, last.y], abs=1e-6)
        moved = math.dist(first[:2], second[:2])
        assert moved == pytest.approx(math.dist((run.records[9].x, run.records[9].y), (last.x, last.y)), abs=1e-6)
        assert moved > 2.0

        levels = browser.wait_for(
            "(() => { const l = [...document.querySelectorAll('#anchors [data-anchor]')].map(g => g.dataset.level);"
            " return l.includes('STALE') ? l : null; })()", "anchor levels from the health snapshot")
        assert levels == ["OK", "OK", "WARN", "STALE"]
        assert browser.eval("+document.getElementById('particles').dataset.count") == MAX_PARTICLES
        # The drawn 95 % ellipse is the record's covariance.
        rx, ry, ang = browser.eval("(() => { const e = document.getElementById('ellipse'); "
                                   "return [+e.dataset.rx, +e.dataset.ry, +e.dataset.angle]; })()")
        w, v = np.linalg.eigh(np.array([[last.cov[0], last.cov[1]], [last.cov[1], last.cov[2]]]))
        assert (rx, ry) == pytest.approx((math.sqrt(5.991 * w[1]), math.sqrt(5.991 * w[0])), rel=1e-4)
        major = v[:, 1]
        assert abs(math.cos(ang) * major[0] + math.sin(ang) * major[1]) == pytest.approx(1.0, abs=1e-4)
        track_points = browser.eval("document.getElementById('track').getAttribute('points').split(' ').length")
        assert track_points == 30
        assert browser.eval("window.pfdoaState.health.line") == run.snapshots[1][1]

        shot = tmp_path / "live-view.png"
        browser.screenshot(shot)
        assert shot.stat().st_size > 10_000


# -- rooms, floors and the scale ------------------------------------------------------------

ROOMS_SHOWN = ("[...document.querySelectorAll('#rooms [data-room]')].filter(g => getComputedStyle(g).display !== "
               "'none').map(g => g.dataset.room).sort()")


def test_page_draws_rooms_a_scale_and_a_floor_selector(browser, tmp_path):
    """The two-floor house (pfdoasim.building) replayed by pfdoa replay: its records, fed to
    the sink, draw the rooms of the estimate's floor with its room highlighted; the floor
    buttons show the other floor; the scale bar is a round length in site metres. The
    screenshot is build/live-view-rooms.png (PFDOA_UPDATE_SCREENSHOT=1: also
    docs/img/live-view-rooms.png)."""
    import os
    import shutil
    from pathlib import Path

    from pfdoa.output import Record
    from pfdoa.rooms import site_plan
    from pfdoasim.building import BuildingConfig, run_building, two_floor_site

    cfg = BuildingConfig(seed=3, duration_s=60.0)
    run_building(cfg, tmp_path)
    recs = [json.loads(ln) for ln in (tmp_path / "building-3" / "estimates.jsonl").read_text().splitlines()]
    site = two_floor_site(cfg)
    plan = site_plan(site)
    # Up to the first estimate on the first floor that is in a room, well after the stair.
    on_first = [k for k, r in enumerate(recs) if r["floor"] == "first" and r["room"] and r["room_p"] > 0.5]
    end = next(k for k in on_first if k > on_first[0] + 25)
    with WebSink("127.0.0.1:0", site) as sink:
        for r in recs[:end + 1]:
            sink.write(Record(**{k: v for k, v in r.items() if k in Record.__dataclass_fields__}))
        last = recs[end]
        browser.navigate(sink.url)
        # (the page may still be loading: no element yet is not an error)
        browser.wait_for(f"(() => {{ const g = document.getElementById('estimate'); "
                         f"return g !== null && +g.dataset.n === {end + 1}; }})()", "the last estimate")
        rooms = browser.eval("[...document.querySelectorAll('#rooms [data-room]')].map(g => "
                             "[g.dataset.room, g.dataset.floor, g.querySelector('polygon').getAttribute('points')])")
        assert [(n, f) for n, f, _ in rooms] == [(r.name, r.floor) for r in plan.rooms]
        for (_n, _f, points), room in zip(rooms, plan.rooms):  # drawn in site metres (y flipped)
            drawn = [tuple(map(float, p.split(","))) for p in points.split()]
            assert len(drawn) == len(room.polygon)
            assert np.ptp([p[0] for p in drawn]) == pytest.approx(np.ptp([p[0] for p in room.polygon]))
        # auto: the estimate's floor (first) is on show, the ground floor's rooms and anchors hidden.
        assert browser.eval(ROOMS_SHOWN) == sorted(r.name for r in plan.rooms if r.floor == "first")
        assert browser.eval("document.getElementById('map').dataset.floor") == "first"
        anchors_shown = browser.eval("[...document.querySelectorAll('#anchors [data-anchor]')].filter(g => "
                                     "getComputedStyle(g).display !== 'none').map(g => +g.dataset.anchor)")
        assert anchors_shown == [a.id for a, f in zip(site.anchors, plan.anchor_floors) if plan.floors[f].name == "first"]
        here = browser.eval("[...document.querySelectorAll('#rooms polygon.here')].map(p => "
                            "p.parentNode.dataset.room)")
        assert here == [last["room"]]
        assert browser.eval("document.getElementById('estimate').dataset.room") == last["room"]
        assert browser.eval("document.getElementById('est').textContent").count(f"{last['room']} (") == 1
        buttons = browser.eval("[...document.querySelectorAll('#floors button')].map(b => "
                               "[b.dataset.floor, b.classList.contains('on'), b.classList.contains('current')])")
        assert buttons == [["auto", True, False], ["ground", False, False], ["first", False, True]]
        # The scale bar: a round length (plan 10 m + margins: 2 m), drawn that long in site metres.
        bar = browser.eval("(() => { const g = document.getElementById('scalebar'); const l = g.querySelector('line');"
                           " return [+g.dataset.m, +l.getAttribute('x2') - +l.getAttribute('x1'), "
                           "g.querySelector('text').textContent]; })()")
        assert bar[0] == 2 and bar[1] == pytest.approx(2.0) and bar[2] == "2 m"
        shot = Path(__file__).resolve().parents[2] / "build" / "live-view-rooms.png"
        shot.parent.mkdir(exist_ok=True)
        browser.screenshot(shot)
        assert shot.stat().st_size > 10_000
        if os.environ.get("PFDOA_UPDATE_SCREENSHOT"):
            shutil.copy(shot, Path(__file__).resolve().parents[2] / "docs" / "img" / "live-view-rooms.png")
        # Choosing the ground floor shows its rooms and anchors instead.
        browser.eval("document.querySelector('#floors button[data-floor=\"ground\"]').click()")
        assert browser.eval(ROOMS_SHOWN) == sorted(r.name for r in plan.rooms if r.floor == "ground")
        assert browser.eval("document.getElementById('map').dataset.floor") == "ground"
