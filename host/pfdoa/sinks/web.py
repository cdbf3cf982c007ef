"""Live view: an HTTP server with one page of the floor plan (``--web [HOST:]PORT``).

The page (``pfdoa/web/index.html``, no build step) polls ``/state.json`` and draws the
anchors coloured by health, the particle cloud, the estimate with its 95 % uncertainty
ellipse (from ``cov``), the recent track, the health counters, a scale bar and, for a
site with ``[[rooms]]`` and ``[[floors]]`` (:mod:`pfdoa.rooms`), the rooms (the estimate's
own highlighted) and a floor selector (``auto`` follows the estimate's floor; another floor
shows its rooms and anchors).

Bounded whatever the browsers do: the pipeline thread only swaps the latest state under a
lock (:meth:`WebSink.write` never touches a socket); each request serialises that state
when it is asked for, so a slow browser just sees fewer updates (latest state wins, nothing
queues). The track keeps the last ``track`` positions; at most ``MAX_PARTICLES`` particles
are kept.

Slow or stuck clients never keep the others out. At most ``max_clients`` connections are
served at once, each under a deadline on the server's monotonic clock (injected in tests):
a whole request (its line and headers, or the wait for the next one on a kept-alive
connection) within ``header_timeout_s``, a whole response written within
``write_timeout_s``. A connection past its deadline is shut (``timed_out``): a client
trickling a byte every few seconds used to keep its place for ever, since a socket timeout
only bounds each read. A new connection while every place is taken takes the place of the
connection that has waited longest for a request (``evicted``: an idle kept-alive browser
reconnects at its next poll, a trickler is gone); a place already shut (its deadline, an
eviction) whose thread is still ending is waited for, not refused; only when every place
is sending a response is it closed at once (``rejected``).

Binds to 127.0.0.1 unless a host is given: the page shows where the robot is.
"""

from __future__ import annotations

import json
import logging
import math
import socket
import threading
import time
from collections import deque
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Callable

import numpy as np

from pfdoa.errors import InputError
from pfdoa.gateway.health import HealthSnapshot
from pfdoa.sinks.base import Sink, record_cov, record_heading

log = logging.getLogger(__name__)

DEFAULT_HOST = "127.0.0.1"
MAX_PARTICLES = 200
TRACK = 300
MAX_CLIENTS = 8
TIMEOUT_S = 10.0  # each deadline: a whole request, a whole response
POLL_MS = 250  # the page's polling period
REAP_S = 0.2  # how often deadlines are checked (the server loop's poll interval)
EVICT_WAIT_S = 5.0  # at most this long for a shut connection's place to come free

Particles = Callable[[], "np.ndarray | None"]


def parse_address(spec: str, what: str = "--web") -> tuple[str, int]:
    """``PORT``, ``HOST:PORT`` or ``[IPv6]:PORT`` -> (host, port); host defaults to 127.0.0.1.

    Port 0 picks a free port. Anything else is an :class:`InputError` naming ``what``.
    """
    s = spec.strip()
    host = DEFAULT_HOST
    port_text = s
    if s.startswith("["):
        end = s.find("]")
        if end < 0 or s[end + 1:end + 2] != ":":
            raise InputError(f"{what} {spec!r}: expected [HOST:]PORT, e.g. 8080, 0.0.0.0:8080 or [::1]:8080")
        host, port_text = s[1:end], s[end + 2:]
    elif ":" in s:
        host, _, port_text = s.rpartition(":")
        if ":" in host:
            raise InputError(f"{what} {spec!r}: an IPv6 host goes in brackets: [::1]:8080")
    if not host:
        raise InputError(f"{what} {spec!r}: empty host before ':'")
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise InputError(f"{what} {spec!r}: port must be a number in 0..65535, got {port_text!r}")
    return host, int(port_text)


def _page() -> bytes:
    return resources.files("pfdoa").joinpath("web", "index.html").read_bytes()


def _num(v, digits: int = 6):
    if v is None:
        return None
    v = float(v)
    return round(v, digits) if math.isfinite(v) else None


class _Conn:
    """A served connection: what it is doing (``request``: waiting for one; ``respond``:
    being answered), since when, and its deadline (the server's monotonic clock)."""

    __slots__ = ("state", "since", "deadline")

    def __init__(self, state: str, since: float, deadline: float) -> None:
        self.state, self.since, self.deadline = state, since, deadline


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    sink: "WebSink"

    def __init__(self, addr, handler, sink: "WebSink") -> None:
        self.address_family = socket.AF_INET6 if ":" in addr[0] else socket.AF_INET
        self.sink = sink
        self.slots = threading.BoundedSemaphore(sink.max_clients)
        self.conns: dict[socket.socket, _Conn] = {}  # the connections being served (at most max_clients)
        self.conns_lock = threading.Lock()
        super().__init__(addr, handler)

    # -- deadlines (see the module doc) ---------------------------------------------------
    def accepted(self, sock: socket.socket) -> None:
        """``sock`` waits for its first request from the accept on, before its thread runs:
        the next accept's eviction must see it (else a connection whose thread had not started
        yet was skipped and a newer one evicted in its place)."""
        now = self.sink.clock()
        with self.conns_lock:
            self.conns[sock] = _Conn("request", now, now + self.sink.header_timeout_s)

    def phase(self, sock: socket.socket, state: str) -> None:
        """``sock`` starts waiting for a request, or answering one: its deadline starts now."""
        sink = self.sink
        now = sink.clock()
        limit = sink.header_timeout_s if state == "request" else sink.write_timeout_s
        with self.conns_lock:
            held = self.conns.get(sock)
            if held is None:
                return  # shut already (deadline, eviction), perhaps before its thread ran
            if held.state == state == "request":
                return  # registered at accept: it has waited since then
            self.conns[sock] = _Conn(state, now, now + limit)

    def done(self, sock: socket.socket) -> None:
        with self.conns_lock:
            self.conns.pop(sock, None)

    def service_actions(self) -> None:
        """Every REAP_S (serve_forever's loop): shut connections past their deadline."""
        now = self.sink.clock()
        with self.conns_lock:
            late = [s for s, c in self.conns.items() if now >= c.deadline]
            for s in late:
                del self.conns[s]
        for s in late:
            self.sink.timed_out += 1
            _shut(s)

    def _evict(self) -> bool:
        """Shut the connection that has waited longest for a request (see the module doc)."""
        with self.conns_lock:
            waiting = [(c.since, id(s), s) for s, c in self.conns.items() if c.state == "request"]
            if not waiting:
                return False
            victim = min(waiting)[2]
            del self.conns[victim]
        self.sink.evicted += 1
        _shut(victim)
        return True

    def _freeing(self) -> bool:
        """A place is held by a connection already shut (deadline, eviction) whose thread has
        not returned yet: it comes free without shutting another."""
        with self.conns_lock:
            return len(self.conns) < self.sink.max_clients

    def process_request(self, request, client_address) -> None:
        if not self.slots.acquire(blocking=False):
            if not ((self._freeing() or self._evict()) and self.slots.acquire(timeout=EVICT_WAIT_S)):
                self.sink.rejected += 1
                self.shutdown_request(request)
                return
        self.accepted(request)
        try:
            super().process_request(request, client_address)
        except Exception:
            self.done(request)
            self.slots.release()
            raise

    def process_request_thread(self, request, client_address) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self.slots.release()

    def handle_error(self, request, client_address) -> None:
        log.debug("web: error serving %s", client_address, exc_info=True)


class _Handler(BaseHTTPRequestHandler):
    server: _Server
    server_version = "pfdoa"
    protocol_version = "HTTP/1.1"

    def setup(self) -> None:
        sink = self.server.sink
        # Each read and write: a backstop only (the deadlines bound the whole, on their clock).
        self.timeout = 2.0 * max(sink.header_timeout_s, sink.write_timeout_s) + 1.0
        super().setup()

    def handle_one_request(self) -> None:
        self.server.phase(self.connection, "request")
        super().handle_one_request()

    def finish(self) -> None:
        self.server.done(self.connection)
        try:
            super().finish()
        except OSError:  # shut for its deadline while its last bytes were on the way
            pass

    def log_message(self, fmt: str, *args) -> None:
        log.debug("web: %s " + fmt, self.address_string(), *args)

    def _send(self, code: int, body: bytes, ctype: str) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def do_GET(self) -> None:
        self.server.phase(self.connection, "respond")
        path = self.path.split("?", 1)[0]
        sink = self.server.sink
        sink.requests += 1
        if path in ("/", "/index.html"):
            self._send(200, sink.page, "text/html; charset=utf-8")
        elif path == "/state.json":
            self._send(200, sink.state_json(), "application/json")
        else:
            self._send(404, b"not found\n", "text/plain; charset=utf-8")

    do_HEAD = do_GET


def _shut(sock: socket.socket) -> None:
    """End a connection from another thread: its handler's blocked read or write returns."""
    try:
        sock.shutdown(socket.SHUT_RDWR)
    except OSError:  # already closed by its handler
        pass


def _view_bounds(site) -> list[float]:
    """What the floor plan shows: the anchors and, when the site has one, its area."""
    x0, y0, x1, y1 = site.bounds
    area = getattr(site, "area", None)
    if area is not None:
        x0, y0, x1, y1 = min(x0, area[0]), min(y0, area[1]), max(x1, area[2]), max(y1, area[3])
    return [x0, y0, x1, y1]


def _site_view(site, title: str | None) -> dict:
    """The site as the page draws it: anchors (with their floor), rooms, floors, bounds."""
    from pfdoa.rooms import site_plan

    plan = site_plan(site) if hasattr(site, "sections") else None
    floors = plan.floors if plan is not None else ()
    anchor_floor = [floors[k].name for k in plan.anchor_floors] if plan is not None and plan.anchor_floors else []
    bounds = _view_bounds(site)
    for room in plan.rooms if plan is not None else ():
        xs, ys = [p[0] for p in room.polygon], [p[1] for p in room.polygon]
        bounds = [min(bounds[0], *xs), min(bounds[1], *ys), max(bounds[2], *xs), max(bounds[3], *ys)]
    return {
        "name": title or getattr(site, "name", "") or "",
        "anchors": [{"id": a.id, "x": a.x, "y": a.y, "floor": anchor_floor[i] if anchor_floor else None}
                    for i, a in enumerate(site.anchors)],
        "rooms": [{"name": r.name, "floor": r.floor, "polygon": [list(p) for p in r.polygon]}
                  for r in (plan.rooms if plan is not None else ())],
        "floors": [{"name": f.name, "z": [f.zmin, f.zmax]} for f in floors],
        "bounds": bounds,
    }


class WebSink(Sink):
    """Serves the live view (see the module doc). ``particles``: called after each record
    in the pipeline thread, returns the filter's particle positions (n, 2) or None."""

    name = "web"

    def __init__(self, address: str | tuple[str, int], site, particles: Particles | None = None,
                 track: int = TRACK, max_clients: int = MAX_CLIENTS, header_timeout_s: float = TIMEOUT_S,
                 write_timeout_s: float = TIMEOUT_S, title: str | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        host, port = parse_address(address) if isinstance(address, str) else address
        self.site = site
        self.particles_source = particles
        self.max_clients = int(max_clients)
        self.header_timeout_s = float(header_timeout_s)
        self.write_timeout_s = float(write_timeout_s)
        self.clock = clock
        self.page = _page()
        self.requests = 0
        self.rejected = 0  # closed at once: every place was sending a response
        self.evicted = 0  # shut for a new connection: it had waited longest for a request
        self.timed_out = 0  # shut at its deadline
        self._lock = threading.Lock()
        self._version = 0
        self._track: deque[tuple[float, float]] = deque(maxlen=int(track))
        self._estimate: dict | None = None
        self._particles: list[list[float]] = []
        self._health: dict | None = None
        self._records = 0
        self._particle_errors = 0
        self._site = _site_view(site, title)
        try:
            self._server = _Server((host, port), _Handler, self)
        except OSError as exc:
            raise InputError(f"--web {host}:{port}: cannot listen: {exc.strerror or exc}") from None
        self.host, self.port = self._server.server_address[:2]
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": REAP_S},
                                        name="web", daemon=True)
        self._thread.start()
        log.info("live view on %s", self.url)

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    def _take_particles(self) -> list[list[float]]:
        if self.particles_source is None:
            return []
        try:
            p = self.particles_source()
        except Exception as exc:  # the view must never stop the gateway
            if not self._particle_errors:
                log.warning("web: particle snapshot failed: %s", exc)
            self._particle_errors += 1
            return []
        if p is None:
            return []
        p = np.asarray(p, dtype=float)
        if p.ndim != 2 or p.shape[1] < 2 or not len(p):
            return []
        if len(p) > MAX_PARTICLES:  # evenly spread over the array (particles are in no order)
            p = p[np.linspace(0, len(p) - 1, MAX_PARTICLES).round().astype(int)]
        return np.round(p[:, :2], 3).tolist()

    def write(self, record) -> None:
        cov = record_cov(record)
        h = record_heading(record)
        est = {
            "t": _num(record.t), "x": _num(record.x), "y": _num(record.y), "sigma": _num(record.sigma),
            "cov": None if cov is None else [_num(v, 8) for v in cov],
            "heading": None if h is None else _num(h[0]), "seq": record.seq,
            "anchors": [int(a) for a in record.anchors], "missing": [int(a) for a in record.missing],
            "stale": [int(a) for a in record.stale],
            "room": getattr(record, "room", None), "room_p": _num(getattr(record, "room_p", None), 4),
            "floor": getattr(record, "floor", None), "floor_p": _num(getattr(record, "floor_p", None), 4),
        }
        particles = self._take_particles()
        with self._lock:
            self._records += 1
            self._version += 1
            est["n"] = self._records
            self._estimate = est
            if math.isfinite(float(record.x)) and math.isfinite(float(record.y)):
                self._track.append((round(float(record.x), 4), round(float(record.y), 4)))
            if self.particles_source is not None:
                self._particles = particles

    def health(self, snapshot: HealthSnapshot) -> None:
        doc = snapshot.to_json()
        doc["line"] = snapshot.line()
        with self._lock:
            self._version += 1
            self._health = doc

    def state(self) -> dict:
        """The page's data: site, estimate, track, particles, health, counters."""
        with self._lock:
            return {
                "version": self._version,
                "site": self._site,
                "estimate": self._estimate,
                "track": list(self._track),
                "particles": self._particles,
                "health": self._health,
                "records": self._records,
                "poll_ms": POLL_MS,
            }

    def state_json(self) -> bytes:
        return json.dumps(self.state(), separators=(",", ":"), allow_nan=False).encode()

    def _close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(timeout=5.0)
