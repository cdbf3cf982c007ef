"""The gateway fast paths added for `make bench` keep the exact behaviour.

* AnchorTracker.update_stale skips its scan until an anchor could turn stale: staleness
  must still be detected at the same poll as a full scan would, also when reading times
  go backwards (replayed captures from several sources).
* Gateway._sync_errors skips the counter scan while the decoder discarded nothing: every
  decode error must still reach Health.
* SeqReassembler.poll returns at once when its time has not advanced and no anchor can turn
  stale: that relies on every push and poll leaving the oldest open set not ready at the
  timer time, whatever the readings (losses, duplicates, late and reordered reports,
  restarts, reboots, stale anchors, times going back).
"""

from __future__ import annotations

import copy
import random

from pfdoa.gateway.health import Health
from pfdoa.gateway.pipeline import Gateway
from pfdoa.gateway.transports import Chunk
from pfdoa.protocol.messages import RssiReport
from pfdoa.protocol.uart import StreamDecoder, encode_uart
from pfdoa.readings.reassembly import AnchorTracker, Reading, SeqReassembler


def _full_scan(tr: AnchorTracker, now: float) -> tuple[int, ...]:
    """What update_stale returned before the fast path: every anchor silent too long."""
    out = []
    for a in tr.anchor_ids:
        last = tr.stats(a).last_rx
        last = tr.start if last is None else last
        if now - last > tr.stale_after_s:
            out.append(a)
    return tuple(out)


def test_stale_detected_at_the_same_poll_as_a_full_scan() -> None:
    rng = random.Random(3)
    tr = AnchorTracker((1, 2, 3), stale_after_s=1.0)
    t = 0.0
    for _ in range(3000):
        t += rng.choice((0.01, 0.05, 0.3))
        a = rng.choice((1, 2, 3, 3, 3))
        if rng.random() < 0.7:
            # Non-monotonic reading times, as from several replayed sources.
            tr.seen(Reading(a, -60.0, t - rng.choice((0.0, 0.0, 0.8, 2.5)), None, None))
        expect = _full_scan(tr, t) if tr.start is not None else ()
        got = tr.update_stale(t)
        assert got == expect, (t, got, expect)
        assert tr.stale_ids() == expect


def test_an_anchor_that_stops_turns_stale_after_quiet_polls() -> None:
    tr = AnchorTracker((1, 2), stale_after_s=3.0)
    for k in range(100):
        t = 0.02 * k
        tr.seen(Reading(1, -60.0, t, None, None))
        tr.seen(Reading(2, -60.0, t, None, None))
        assert tr.update_stale(t) == ()
    for k in range(100, 400):  # anchor 2 silent from t = 1.98 s
        t = 0.02 * k
        tr.seen(Reading(1, -60.0, t, None, None))
        got = tr.update_stale(t)
        assert got == ((2,) if t - 1.98 > 3.0 else ()), t
    assert tr.stats(2).stale_events == 1


def test_every_decode_error_reaches_health() -> None:
    rng = random.Random(5)
    frames = [encode_uart(RssiReport(s, 20 * s, -15000, -60, 3, 37, 0), 1 + s % 4) for s in range(400)]
    stream = bytearray()
    for f in frames:
        stream += f
        if rng.random() < 0.2:  # junk, ending with a delimiter: one decode error (or none if empty)
            stream += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 90))) + b"\x00"
    ref = StreamDecoder()
    ref.feed(bytes(stream))
    health = Health()
    gw = Gateway(SeqReassembler((1, 2, 3, 4)), lambda s: None, health)
    pos = 0
    while pos < len(stream):
        k = rng.randrange(1, 70)
        gw.feed(Chunk("serial0", pos * 1e-4, bytes(stream[pos:pos + k])))
        pos += k
    want = {k: v for k, v in ref.counters.items() if v and k not in ("frames_ok", "bytes_in", "bytes_discarded")}
    assert want, "the stream must contain decode errors"
    assert dict(health.errors) == want


def test_seq_poll_skips_only_when_a_full_poll_would_do_nothing() -> None:
    rng = random.Random(11)
    g = SeqReassembler((1, 2, 3, 4), set_timeout_s=0.25, max_open_sets=6, stale_after_s=1.0, history=32)
    t, seq, tick = 0.0, 100, {a: 5000 * a for a in (1, 2, 3, 4)}
    skipped = 0
    for _ in range(6000):
        t += rng.choice((0.0, 0.0, 0.01, 0.02, 0.3, 1.5, -0.4))
        seq = (seq + rng.choice((1, 1, 1, 0, -1, 2, 40))) & 0xFFFF
        if rng.random() < 0.002:
            seq = rng.randrange(0x10000)  # the beacon restarts its numbering
        a = rng.choice((1, 2, 3, 3, 4, 4, 9))
        if a in tick:
            tick[a] += rng.choice((20, 20, 20, -3000))  # ... or an anchor reboots
        g.push(Reading(a, -60.0, t, seq if rng.random() < 0.95 else None, tick.get(a)))
        if rng.random() < 0.05:
            g.tracker.uptime(rng.choice((1, 2, 3, 4)), rng.randrange(100), t)
        for _ in range(rng.choice((0, 1, 1, 2))):
            now = t + rng.choice((0.0, 0.0, -0.1, 0.05, 2.0))
            full = copy.deepcopy(g)
            full._now = max(full._now, now)
            full.tracker.update_stale(now)
            want = full._drain(full._now)
            if now <= g._now and now < g.tracker._quiet_until:
                skipped += 1
                assert want == [], (now, g._now)
            assert g.poll(now) == want
    assert skipped > 1000
