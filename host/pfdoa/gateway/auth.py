"""The gateway's side of our authenticated rolling beacon (protocol/SPEC.md 9.6): key files,
the second verification of every report, and what can be detected of a real-time relay.

Keys live in key files of their own (:func:`load_key_file`, :func:`write_key_file`), which
a site file's ``[[beacons]]`` entry names (``kind = "pfdoa_auth"``, ``key_file =
"robot1.key"``, relative to the site file): the site file stays shareable, the key file is
secret. A key file is one line of 32 hex digits (``#`` comments allowed), readable by its
owner only (mode 0600 or stricter): a key file others may read or write is refused.

:class:`AuthGuard` (one per ``pfdoa_auth`` beacon) checks each ``AUTH_REPORT`` an anchor
sends: its tag against the key (``bad_tag``), its counter against the beacon's window
(``stale``), its (counter, seq) against that anchor's last one (``replayed``; the very same
report again, tick included, is a duplicate on the link and left to the reassembler).
An ``RSSI_REPORT`` of such a beacon (the CAN mapping has no ``AUTH_REPORT``) is the anchor's
word alone: accepted and counted ``unverified``. Relays: a set whose RSSI pattern no
position of the site explains (``relay_pattern``) and an estimate further from the last one
than the beacon can move (``relay_jump``) are counted, not dropped (they could be noise, and
dropping them would hand a relay a lever to silence the beacon). :class:`AuthCounters`
holds every count and each anchor's last ``AUTH_STATUS`` (its own rejections); the health
summary shows them. Keys are never logged or written anywhere but a key file.
"""

from __future__ import annotations

import hmac
import logging
import math
import os
import secrets
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pfdoa.errors import ConfigError
from pfdoa.protocol import auth, defs
from pfdoa.protocol.messages import AuthReport, AuthStatus, RssiReport

log = logging.getLogger(__name__)

REASONS = auth.REJECTIONS  # bad_tag, stale, replayed
MAX_KEY_FILE = 4096  # bytes read of a key file at most
# Relay detection. A set of at least PATTERN_MIN_ANCHORS values whose RMS residual to the
# radio model is above RELAY_RESIDUAL_DB at every point of a PATTERN_GRID_M grid over the
# site (and PATTERN_MARGIN_M around it) is "relay_pattern": no single transmitter explains
# it. An estimate further from the previous one than MAX_SPEED_MPS x dt + JUMP_MARGIN_M is
# "relay_jump". Both bounds are above what the simulator's noisy, shadowed rooms produce
# (tests/unit/test_gateway_auth.py measures the clean rates).
PATTERN_MIN_ANCHORS = 3
RELAY_RESIDUAL_DB = 7.0
PATTERN_GRID_M = 0.25
PATTERN_MARGIN_M = 1.0
MAX_SPEED_MPS = 3.0
JUMP_MARGIN_M = 1.5


def load_key_file(path: str | Path, source: str, where: str) -> bytes:
    """The key in ``path`` (ConfigError naming ``source`` and ``where``, never the key)."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        raise ConfigError(source, where, f"cannot read key file {p}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(source, where, f"key file {p} is not a regular file")
    if os.name == "posix" and st.st_mode & 0o077:
        raise ConfigError(source, where, f"key file {p} may be read or written by others (mode "
                          f"{stat.S_IMODE(st.st_mode):04o}): chmod 600 {p}")
    try:
        with open(p, "rb") as fh:
            raw = fh.read(MAX_KEY_FILE + 1)
    except OSError as exc:
        raise ConfigError(source, where, f"cannot read key file {p}: {exc.strerror or exc}") from None
    if len(raw) > MAX_KEY_FILE:
        raise ConfigError(source, where, f"key file {p} is longer than {MAX_KEY_FILE} bytes")
    lines = []
    for line in raw.decode("ascii", errors="replace").splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            lines.append(line)
    if len(lines) != 1 or len(lines[0]) != 2 * defs.AUTH_KEY_LEN:
        raise ConfigError(source, where, f"key file {p} must hold one line of {2 * defs.AUTH_KEY_LEN} hex digits")
    try:
        return bytes.fromhex(lines[0])
    except ValueError:
        raise ConfigError(source, where, f"key file {p} must hold one line of {2 * defs.AUTH_KEY_LEN} "
                          "hex digits") from None


def write_key_file(path: str | Path, key: bytes | None = None) -> bytes:
    """Write a new key (random unless given) to a new file readable by its owner only;
    never overwrites. Returns the key."""
    k = auth.check_key(key if key is not None else secrets.token_bytes(defs.AUTH_KEY_LEN))
    fd = os.open(os.fspath(path), os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write("# pfdoa beacon key (protocol/SPEC.md 9): secret, keep it mode 0600\n")
        fh.write(k.hex() + "\n")
    return k


@dataclass
class AuthCounters:
    """Every verdict of the gateway's guards, and each anchor's last AUTH_STATUS."""

    accepted: int = 0
    bad_tag: int = 0
    stale: int = 0
    replayed: int = 0
    unverified: int = 0  # reports of authenticated beacons no key here could check
    relay_pattern: int = 0
    relay_jump: int = 0
    anchors: dict[int, tuple[int, int, int]] = field(default_factory=dict)  # bad_tag, stale, replayed
    configured: bool = False  # a [[beacons]] entry holds a key

    @property
    def active(self) -> bool:
        return self.configured or bool(self.anchors) or self.unverified > 0

    def anchor_status(self, anchor_id: int, m: AuthStatus) -> None:
        self.anchors[anchor_id] = (m.auth_bad_tag, m.auth_stale, m.auth_replayed)

    def anchor_totals(self) -> dict[str, int]:
        return {r: sum(v[i] for v in self.anchors.values()) for i, r in enumerate(REASONS)}

    def summary(self) -> dict[str, Any]:
        return {"accepted": self.accepted, "bad_tag": self.bad_tag, "stale": self.stale, "replayed": self.replayed,
                "unverified": self.unverified, "relay_pattern": self.relay_pattern, "relay_jump": self.relay_jump,
                "anchors": {**self.anchor_totals(),
                            "by_anchor": {str(a): dict(zip(REASONS, v)) for a, v in sorted(self.anchors.items())}}}

    def snapshot(self) -> dict[str, int]:
        """The flat counts a health snapshot carries."""
        out = {r: getattr(self, r) for r in REASONS}
        out.update({f"anchor_{r}": n for r, n in self.anchor_totals().items()})
        out.update(unverified=self.unverified, relay_pattern=self.relay_pattern, relay_jump=self.relay_jump)
        return out


class AuthGuard:
    """One authenticated beacon's second verification and relay checks (module doc).
    ``positions`` (n, 2), ``expected`` a function of points (..., 2) -> RSSI (..., n): the
    site's radio model, for the pattern check (None: no pattern check)."""

    def __init__(self, key: bytes, counters: AuthCounters, anchor_ids=(), positions: np.ndarray | None = None,
                 expected=None, bounds: tuple[float, float, float, float] | None = None) -> None:
        self._key = auth.check_key(key)
        self.counters = counters
        counters.configured = True
        self.window = auth.Window()  # the beacon's counter clock, on the gateway's time
        self._last: dict[int, tuple[auth.Window, int | None]] = {}  # per anchor: last (counter, seq), its tick
        self._ids = list(anchor_ids)
        self._grid: np.ndarray | None = None
        if positions is not None and expected is not None and bounds is not None:
            x0, y0, x1, y1 = bounds
            m, g = PATTERN_MARGIN_M, PATTERN_GRID_M
            xs = np.arange(x0 - m, x1 + m + g / 2, g)
            ys = np.arange(y0 - m, y1 + m + g / 2, g)
            pts = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
            self._grid = np.asarray(expected(pts), dtype=float)  # (points, anchors)
        self._last_pos: tuple[float, float, float] | None = None

    def __repr__(self) -> str:  # never the key
        return f"AuthGuard(key check {auth.key_check(self._key)[:4].hex()})"

    def accept(self, anchor_id: int, m: RssiReport, t: float) -> bool:
        """Whether a report of this beacon goes on to the reassembler (counted either way)."""
        c = self.counters
        if not isinstance(m, AuthReport):
            c.unverified += 1  # CAN has no AUTH_REPORT: the anchor verified it, this cannot
            return True
        if not hmac.compare_digest(auth.tag(self._key, m.counter, m.seq), m.tag):
            c.bad_tag += 1
            return False
        ms = int(math.floor(t * 1000.0)) & auth.U32
        w = self.window
        if w.have and m.counter + defs.AUTH_WINDOW < w.expected(ms):
            c.stale += 1
            return False
        last = self._last.get(anchor_id)
        if last is not None:
            lw, tick = last
            if (m.counter, m.seq) == (lw.counter, lw.seq) and m.tick_ms == tick:
                return True  # the same frame twice on the link: the reassembler's duplicate
            if lw.check(m.counter, m.seq, ms, same_event_ms=None) != defs.AUTH_ACCEPT:
                c.replayed += 1
                return False
        else:
            lw = auth.Window()
            lw.check(m.counter, m.seq, ms, same_event_ms=None)
        self._last[anchor_id] = (lw, m.tick_ms)
        if not w.have or m.counter > w.counter or (m.counter == w.counter and auth.seq_newer(m.seq, w.seq)):
            w.have, w.counter, w.seq, w.tick = True, m.counter, m.seq, ms
        c.accepted += 1
        return True

    def residual_db(self, rssi: dict[int, float]) -> float | None:
        """The smallest RMS difference (dB) between the set's values and the model at any
        grid point; None without enough anchors or a grid."""
        if self._grid is None:
            return None
        idx = [i for i, a in enumerate(self._ids) if a in rssi and math.isfinite(rssi[a])]
        if len(idx) < PATTERN_MIN_ANCHORS:
            return None
        r = np.array([rssi[self._ids[i]] for i in idx])
        d = self._grid[:, idx] - r
        return float(np.sqrt((d * d).mean(axis=1).min()))

    def check_set(self, s) -> None:
        """A set of this beacon (pfdoa.gateway.reassembly.AnchorSet) before it is estimated."""
        res = self.residual_db(s.rssi)
        if res is not None and res > RELAY_RESIDUAL_DB:
            self.counters.relay_pattern += 1

    def check_record(self, rec) -> None:
        """An estimate of this beacon (pfdoa.output.Record)."""
        x, y, t = getattr(rec, "x", None), getattr(rec, "y", None), getattr(rec, "t", None)
        if x is None or y is None or t is None or not (math.isfinite(x) and math.isfinite(y)):
            return
        if self._last_pos is not None:
            x0, y0, t0 = self._last_pos
            if math.hypot(x - x0, y - y0) > MAX_SPEED_MPS * max(t - t0, 0.0) + JUMP_MARGIN_M:
                self.counters.relay_jump += 1
        self._last_pos = (x, y, t)


__all__ = ["AuthCounters", "AuthGuard", "load_key_file", "write_key_file", "REASONS"]
