"""The gateway's side of our authenticated beacon (protocol/SPEC.md 9.6, pfdoa.gateway.auth):
key files and their permissions, a pfdoa_auth [[beacons]] entry, the second verification
of every report with its rejections counted by reason in the health, the anchors'
AUTH_STATUS, the relay checks, keys never in a log, a summary or an output, and
`pfdoa anchors keygen`."""

from __future__ import annotations

import json
import logging
import math
import stat
import subprocess
import sys

import numpy as np
import pytest

from pfdoa.errors import ConfigError
from pfdoa.gateway.auth import AuthCounters, AuthGuard, load_key_file, write_key_file
from pfdoa.gateway.beacons import beacons_config
from pfdoa.gateway.health import Health
from pfdoa.gateway.reassembly import AnchorSet
from pfdoa.gateway.setup import build_pipeline, load_settings
from pfdoa.gateway.transports import Chunk
from pfdoa.protocol import auth, defs, encode_uart
from pfdoa.protocol.messages import AuthReport, AuthStatus, RssiReport, Status
from pfdoa.radio import PathLoss, mean_rssi

from gateway_feed import ANCHORS, RADIO, TEST_SITE

pytestmark = pytest.mark.unit

KEY = bytes.fromhex("8f1e2d3c4b5a69788796a5b4c3d2e1f0")
POS = (1.5, 2.5)
C0 = 432_900_000


def entry(key_file: str = "robot.key") -> str:
    return f'\n[[beacons]]\nname = "robot"\nkind = "pfdoa_auth"\nkey_file = "{key_file}"\n'


def rssi_at(p) -> np.ndarray:
    return mean_rssi(np.array(p), np.array(list(ANCHORS.values())), PathLoss(*RADIO))


def auth_frames(k: int, counter: int, *, tag: bytes | None = None, tick_off: int = 0, anchors=ANCHORS) -> bytes:
    """Beacon event k (seq k, `counter`) at every anchor, as AUTH_REPORTs."""
    out = b""
    for (a, _), r in zip(ANCHORS.items(), rssi_at(POS)):
        if a not in anchors:
            continue
        q8 = int(round(float(r) * 256))
        t = tag if tag is not None else auth.tag(KEY, counter, k)
        out += encode_uart(AuthReport(k, 1000 + 100 * k + tick_off, q8, int(round(float(r))), 3, 37, 0, 0, counter, t), a)
    return out


def run(tmp_path, chunks):
    site = tmp_path / "site.toml"
    site.write_text(TEST_SITE + entry())
    write_key_file(tmp_path / "robot.key", KEY)
    out = tmp_path / "out.jsonl"
    pipe = build_pipeline(load_settings(str(site), str(out), "jsonl"), method="trilateration", seed=3)
    for t, data in chunks:
        pipe.gateway.feed(Chunk("serial0", t, data))
        pipe.gateway.poll(t)
    pipe.gateway.finish()
    pipe.localizer.finish()
    pipe.close()
    return [json.loads(line) for line in out.read_text().splitlines()], pipe.summary(), pipe


# ------------------------------------------------------------------------- key files


def test_key_files_are_read_only_when_private_and_well_formed(tmp_path):
    p = tmp_path / "k.key"
    assert write_key_file(p, KEY) == KEY
    assert stat.S_IMODE(p.stat().st_mode) == 0o600
    assert load_key_file(p, "site.toml", "beacons[0].key_file") == KEY
    with pytest.raises(FileExistsError):
        write_key_file(p)  # never overwritten
    cases = {
        "group_readable": (0o640, KEY.hex(), "may be read or written by others (mode 0640): chmod 600"),
        "world_readable": (0o604, KEY.hex(), "mode 0604"),
        "short": (0o600, KEY.hex()[:-2], "one line of 32 hex digits"),
        "not_hex": (0o600, "zz" * 16, "one line of 32 hex digits"),
        "two_keys": (0o600, KEY.hex() + "\n" + KEY.hex(), "one line of 32 hex digits"),
        "huge": (0o600, "#" * 5000 + "\n" + KEY.hex(), "longer than 4096 bytes"),
    }
    for name, (mode, text, msg) in cases.items():
        f = tmp_path / f"{name}.key"
        f.write_text(text + "\n")
        f.chmod(mode)
        with pytest.raises(ConfigError) as e:
            load_key_file(f, "site.toml", "beacons[0].key_file")
        assert msg in str(e.value) and "beacons[0].key_file" in str(e.value), name
        assert KEY.hex() not in str(e.value) and KEY.hex()[:8] not in str(e.value)
    for bad in (tmp_path / "missing.key", tmp_path):
        with pytest.raises(ConfigError):
            load_key_file(bad, "site.toml", "beacons[0].key_file")
    ok = tmp_path / "commented.key"
    ok.write_text("# robot 1\n\n  " + KEY.hex() + "  # installed 2026-01-02\n")
    ok.chmod(0o600)
    assert load_key_file(ok, "s", "w") == KEY


def test_a_pfdoa_auth_beacon_names_its_key_file_beside_the_site(tmp_path):
    write_key_file(tmp_path / "robot.key", KEY)
    site = tmp_path / "site.toml"
    site.write_text(TEST_SITE + entry())
    from pfdoa.site import load_site

    cfg = beacons_config(load_site(site).sections, str(site))
    (spec,) = cfg.entries
    assert spec.filter.kind == defs.FILTER_PFDOA_AUTH and spec.filter.match[:16] == KEY and spec.has_seq
    assert KEY.hex() not in repr(cfg) and KEY.hex() not in spec.filter.describe()
    assert cfg.filter_hash is not None  # the public form's: what anchors holding the key report
    with pytest.raises(ConfigError, match=r"beacons\[0\]\.key_file.*missing key"):
        beacons_config({"beacons": [{"kind": "pfdoa_auth"}]}, str(site))
    with pytest.raises(ConfigError, match=r"beacons\[0\]\.period_ms.*unknown key"):
        beacons_config({"beacons": [{"kind": "pfdoa_auth", "key_file": "robot.key", "period_ms": 100}]}, str(site))
    (tmp_path / "robot.key").chmod(0o644)
    with pytest.raises(ConfigError, match="chmod 600"):
        beacons_config(load_site(site).sections, str(site))


def test_keygen_writes_a_private_key_file_and_prints_only_its_check_value(tmp_path):
    p = tmp_path / "new.key"
    r = subprocess.run([sys.executable, "-m", "pfdoa", "anchors", "keygen", str(p)], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr
    key = load_key_file(p, "", "")
    assert stat.S_IMODE(p.stat().st_mode) == 0o600
    assert f"key check {auth.key_check(key)[:4].hex()}" in r.stdout
    assert key.hex() not in r.stdout + r.stderr
    again = subprocess.run([sys.executable, "-m", "pfdoa", "anchors", "keygen", str(p)], capture_output=True,
                           text=True, timeout=60)
    assert again.returncode == 2 and again.stderr.count("\n") == 1 and "never overwritten" in again.stderr
    assert load_key_file(p, "", "") == key


# ------------------------------------------------------------------------- the second verification


def test_reports_are_verified_again_and_rejections_counted_by_reason(tmp_path, caplog):
    caplog.set_level(logging.DEBUG)
    chunks = []
    t = 10.0
    for k in range(40):  # 40 good events, counter C0 then C0 + 1
        chunks.append((t, auth_frames(k, C0 + k // 20)))
        t += 0.1
    bad = auth_frames(40, C0 + 1, tag=b"\x00" * 8)  # 4 forged tags
    replay = auth_frames(5, C0, tick_off=7)  # an old event again from every anchor (other ticks): 4 replays
    dup = auth_frames(39, C0 + 1)  # the very same frames again: link duplicates, not replays
    chunks += [(t, bad), (t + 0.05, replay), (t + 0.06, dup)]
    t += 20.0  # 20 s on: the counter is expected at C0 + 1 + 4
    stale = auth_frames(41, C0 + 1)  # 4 stale
    fresh = auth_frames(42, C0 + 6)
    chunks += [(t + 0.1, stale), (t + 0.2, fresh)]
    chunks.append((t + 0.3, encode_uart(AuthStatus(3, 2, 1), 1) + encode_uart(AuthStatus(0, 5, 0), 2)))
    recs, summary, pipe = run(tmp_path, chunks)
    a = summary["auth"]
    assert (a["bad_tag"], a["stale"], a["replayed"], a["unverified"]) == (4, 4, 4, 0)
    assert a["accepted"] == 4 * 40 + 4  # 40 good events and the fresh one (duplicates go to the reassembler)
    assert summary["duplicates"] == 4
    assert a["anchors"] == {"bad_tag": 3, "stale": 7, "replayed": 1,
                            "by_anchor": {"1": {"bad_tag": 3, "stale": 2, "replayed": 1},
                                          "2": {"bad_tag": 0, "stale": 5, "replayed": 0}}}
    assert len(recs) == 41
    assert max(math.dist((r["x"], r["y"]), POS) for r in recs) < 0.05
    # The health line and snapshot carry the counts; the key is nowhere.
    snap = pipe.health.sampler(pipe.gateway.groupers).sample(1.0, 1.0)
    assert snap.auth["bad_tag"] == 4 and snap.auth["anchor_stale"] == 7
    assert "auth rejected bad_tag=4+3 stale=4+7 replayed=4+1" in snap.line()
    text = json.dumps(summary) + json.dumps(snap.to_json()) + caplog.text + (tmp_path / "out.jsonl").read_text()
    for piece in (KEY.hex(), KEY.hex()[:12], KEY.hex()[-12:]):
        assert piece not in text


def test_rssi_reports_of_an_authenticated_beacon_are_the_anchors_word(tmp_path):
    """Over CAN an anchor sends RSSI_REPORTs (no AUTH_REPORT there): accepted, counted
    unverified. An AUTH_REPORT for an entry without a key here: the same."""
    chunks = []
    for k in range(5):
        data = b""
        for (a, _), r in zip(ANCHORS.items(), rssi_at(POS)):
            data += encode_uart(RssiReport(k, 1000 + 100 * k, int(round(float(r) * 256)), int(round(float(r))), 3, 37, 0), a)
        chunks.append((10.0 + 0.1 * k, data))
    recs, summary, _ = run(tmp_path, chunks)
    assert summary["auth"]["unverified"] == 20 and summary["auth"]["accepted"] == 0 and len(recs) == 5
    h = Health()
    assert not h.auth.active and "auth" not in h.summary(_Grouper())  # nothing about it without a beacon


class _Grouper:
    class counters:  # noqa: N801 - a stand-in with GroupCounters' fields
        readings = duplicates = late = unknown_anchor = sets = complete = partial = timeouts = evicted = 0
        seq_restarts = 0

    class tracker:  # noqa: N801
        @staticmethod
        def all_stats():
            return {}


def test_guard_rules_one_by_one():
    c = AuthCounters()
    g = AuthGuard(KEY, c)
    assert KEY.hex() not in repr(g) and "key check" in repr(g)

    def rep(k, counter, tick, tag=None):
        return AuthReport(k, tick, -15000, -60, 3, 37, 0, 0, counter, tag if tag is not None else auth.tag(KEY, counter, k))

    assert g.accept(1, rep(1, C0, 100), 0.0)
    assert g.accept(2, rep(1, C0, 101), 0.01)  # the same event from another anchor
    assert g.accept(1, rep(1, C0, 100), 0.02)  # the same frame again (a link duplicate)
    assert not g.accept(1, rep(1, C0, 150), 0.03)  # the same event with another tick: a replay
    assert not g.accept(1, rep(2, C0, 200, tag=bytes(8)), 0.1)
    assert g.accept(1, rep(2, C0, 200), 0.1)
    assert not g.accept(1, rep(1, C0 - 3, 300), 0.2)  # 3 periods back: stale
    assert g.accept(3, rep(3, C0 - 2, 300), 0.2)  # 2 periods back, an anchor's first: within the window
    assert (c.accepted, c.bad_tag, c.stale, c.replayed) == (4, 1, 1, 1)
    assert g.accept(1, RssiReport(9, 1, 0, 0, 1, 37, 0), 1.0) and c.unverified == 1
    # The window follows the gateway's clock: 16.9 s (4 periods) later the counter is expected
    # at C0 + 4, and C0 + 1 is stale.
    assert not g.accept(3, rep(5, C0 + 1, 401), 17.0)
    assert g.accept(3, rep(6, C0 + 2, 402), 17.0)  # the oldest counter within the window
    assert c.stale == 2


# ------------------------------------------------------------------------- relays


def test_relay_pattern_check_flags_mixed_sets_and_rarely_clean_ones():
    """4 anchors of the test site, the site's model: sets from one place with 2 dB noise are
    flagged at most 2 % of the time; sets where the two anchors nearest a relay 10 dB louder
    at another place hear the relay are flagged most of the time."""
    ids = list(ANCHORS)
    pos = np.array(list(ANCHORS.values()))
    model = PathLoss(*RADIO)
    c = AuthCounters()
    g = AuthGuard(KEY, c, ids, pos, lambda p: mean_rssi(p, pos, model), (0.0, 0.0, 4.0, 4.0))
    rng = np.random.default_rng(5)
    n = 400
    for _ in range(n):
        p = rng.uniform(0.3, 3.7, size=2)
        r = rssi_at(p) + rng.normal(0, 2.0, 4)
        g.check_set(AnchorSet(0.0, dict(zip(ids, map(float, r))), ()))
    clean = c.relay_pattern
    assert clean <= 0.02 * n
    for _ in range(n):
        p, q = rng.uniform(0.3, 3.7, size=2), rng.uniform(0.3, 3.7, size=2)
        if np.hypot(*(p - q)) < 2.5:
            q = 4.0 - p  # the relay elsewhere in the room
        r = rssi_at(p) + rng.normal(0, 2.0, 4)
        near = np.argsort(np.hypot(*(pos - q).T))[:2]
        r[near] = (rssi_at(q) + 10.0 + rng.normal(0, 2.0, 4))[near]
        g.check_set(AnchorSet(0.0, dict(zip(ids, map(float, r))), ()))
    assert c.relay_pattern - clean >= 0.5 * n, (clean, c.relay_pattern - clean)
    assert g.residual_db({0: -50.0, 1: -50.0}) is None  # two anchors say nothing


def test_jumps_faster_than_the_beacon_can_move_are_counted():
    c = AuthCounters()
    g = AuthGuard(KEY, c)

    class R:
        def __init__(self, x, y, t):
            self.x, self.y, self.t = x, y, t

    for k in range(20):
        g.check_record(R(1.0 + 0.1 * k, 1.0, 0.1 * k))  # 1 m/s
    assert c.relay_jump == 0
    g.check_record(R(5.0, 5.0, 2.1))  # 5 m in 0.1 s
    g.check_record(R(5.1, 5.0, 2.2))
    g.check_record(R(float("nan"), 5.0, 2.3))
    assert c.relay_jump == 1


def test_anchor_status_of_an_anchor_without_the_beacon_still_counts(tmp_path):
    recs, summary, _ = run(tmp_path, [(1.0, encode_uart(Status(1, 0, 1, 0, 0, 0, 0, defs.DEFS_HASH, 0, 4), 3)
                                        + encode_uart(AuthStatus(65535, 0, 2), 3))])
    assert summary["auth"]["anchors"]["bad_tag"] == 65535 and summary["auth"]["anchors"]["replayed"] == 2
    assert recs == []
