"""docs/security.md states the gateway's memory bounds and names the tests behind each
invariant: the stated numbers are the code's constants, the named tests exist, and the
bounds hold under a flood of hostile input."""

import re
from pathlib import Path

from pfdoa.gateway import pipeline, transports
from pfdoa.gateway.config import GatewayConfig
from pfdoa.gateway.health import Health
from pfdoa.gateway.inputs import capture
from pfdoa.gateway.pipeline import Gateway
from pfdoa.gateway.reassembly import MAX_UNKNOWN_IDS, Reading, SeqReassembler
from pfdoa.gateway.transports import Chunk
from pfdoa.protocol import defs
from pfdoa.protocol.messages import RssiReport
from pfdoa.protocol.uart import encode_uart
from pfdoa.trace import MAX_LINE_CHARS, MAX_ROWS

ROOT = Path(__file__).resolve().parents[2]
DOC = (ROOT / "docs" / "security.md").read_text()


def test_stated_bounds_are_the_code_constants():
    cfg = GatewayConfig()
    for text in (f"{defs.MAX_ENCODED} bytes (`MAX_ENCODED`)", f"{pipeline.MAX_DECODERS} (`pipeline.MAX_DECODERS`)",
                 f"{transports.READ_MAX} bytes (`transports.READ_MAX`)", f"default {cfg.queue_size})",
                 f"default {cfg.max_open_sets})", f"<= {MAX_UNKNOWN_IDS} keys",
                 f"{pipeline.ODOM_QUEUE:,} (`pipeline.ODOM_QUEUE`)", f"lines <= {MAX_LINE_CHARS} characters",
                 f"{capture.CAPTURE_MAX_LINE} characters (`CAPTURE_MAX_LINE`)",
                 f"{MAX_ROWS:,} rows (`trace.MAX_ROWS`"):
        assert text in DOC, text
    from pfdoa import radiomap

    for text in (f"{radiomap.MAX_STORED_VALUES:,} cells x anchors stored (`radiomap.MAX_STORED_VALUES`)",
                 f"{radiomap.MAX_TABLE_VALUES:,} values (`radiomap.MAX_TABLE_VALUES`)",
                 f"{radiomap.MAX_AXIS_CELLS} cells an axis (`radiomap.MAX_AXIS_CELLS`)"):
        assert text in DOC, text
    assert SeqReassembler(()).history == 1024 and "`history` = 1024" in DOC
    assert f"`BEACON_SLOTS` = {defs.BEACON_SLOTS} (one reassembler" in DOC


def test_stated_firmware_bounds_are_the_generated_constants():
    n = defs.MAX_ENCODED
    assert f"`PFDOA_MAX_ENCODED` = {n} bytes; the {n + 1}th non-zero byte reports `overlong`" in DOC
    assert "`beacon` < `PFDOA_BEACON_SLOTS`" in DOC


def test_named_tests_and_files_exist():
    for path in set(re.findall(r"`((?:tests|fuzz|firmware|tools)/[\w/.-]+\.(?:py|c))", DOC)):
        assert (ROOT / path).exists(), path
    sources = [p.read_text() for p in list((ROOT / "tests").rglob("*.py")) + list((ROOT / "firmware/tests").glob("*.c"))]
    defined = {m for text in sources for m in re.findall(r"\b(?:def|void) (test_\w+)\b", text)}
    for name in set(re.findall(r"`(test_\w+)`", DOC)):
        assert name in defined or (ROOT / "firmware/tests" / f"{name}.c").exists(), name


def test_hostile_flood_stays_within_the_stated_bounds():
    ids = (1, 2, 3)
    g = SeqReassembler(ids, max_open_sets=64, set_timeout_s=1e9, stale_after_s=1e9)
    gw = Gateway(g, lambda s: None, Health())
    # Reports for ever-new sequence numbers from one anchor (sets never complete), every
    # unknown anchor id, one more byte-stream source than allowed, and an endless frame.
    for k in range(5000):
        gw.feed(Chunk(f"src{k % (pipeline.MAX_DECODERS + 1)}", 0.0, encode_uart(RssiReport(k * 7 & 0xFFFF, k, 0, 0, 1, 37, 0), 1)))
        gw.feed(Chunk("src0", 0.0, encode_uart(RssiReport(k & 0xFFFF, k, 0, 0, 1, 37, 0), k % defs.ANCHOR_BROADCAST)))
        assert g.open_sets <= 64 and len(g._closed) <= g.history
    gw.feed(Chunk("src1", 0.0, b"\x55" * 100_000))
    assert all(d.pending <= defs.MAX_ENCODED for d in gw._decoders.values())
    assert len(gw._decoders) == pipeline.MAX_DECODERS and gw.health.sources_dropped > 0
    assert len(g.counters.unknown_ids) <= MAX_UNKNOWN_IDS and g.counters.unknown_anchor > 0
    assert g.counters.evicted > 0 and gw.health.errors["overlong"] >= 1
    for a in range(1000):  # unknown ids beyond what can be configured: still counted, dict capped
        g.push(Reading(a, -60.0, 0.0, seq=1))
    assert len(g.counters.unknown_ids) <= MAX_UNKNOWN_IDS


def test_stated_radio_numbers_are_the_code_constants():
    """Section 6: the relay checks' bounds, the counter window and the instruction counts it
    quotes are the code's constants and firmware/README.md's measured table."""
    from pfdoa.gateway import auth as gauth

    text = " ".join(DOC.split())
    assert (f"RMS residual to the radio model above {gauth.RELAY_RESIDUAL_DB:g} dB everywhere on a "
            f"{gauth.PATTERN_GRID_M:g} m grid") in text
    assert f"a set of at least {('three', 'four')[gauth.PATTERN_MIN_ANCHORS - 3]} anchors" in text
    assert f"({gauth.MAX_SPEED_MPS:g} m/s x dt + {gauth.JUMP_MARGIN_M:g} m)" in text
    window_s = defs.AUTH_WINDOW * defs.AUTH_PERIOD_MS / 1000
    assert f"more than two periods ({window_s:.1f} s) behind as stale" in text and defs.AUTH_WINDOW == 2
    assert f"moves every {defs.AUTH_PERIOD_MS / 1000:.3f} s" in text
    fw = (ROOT / "firmware" / "README.md").read_text()
    m4 = re.search(r"^\| Cortex-M4 \| [\d,]+ \| ([\d,]+) \| [\d,]+ \| ([\d,]+) \|", fw, re.M)
    m0 = re.search(r"^\| Cortex-M0\+ \| [\d,]+ \| ([\d,]+) \| [\d,]+ \| ([\d,]+) \|", fw, re.M)
    assert m4 is not None and m0 is not None
    assert f"a replay costs {m4.group(2)} Thumb instructions on the Cortex-M4, {m0.group(2)} on the M0+" in text


def test_fleet_recording_and_live_view_bounds_stated_are_the_code_constants():
    """docs/fleet.md, docs/robot.md and this file state issue 48's bounds as the code has them."""
    from pfdoa.gateway import msgtime, runner
    from pfdoa.gateway.beacons import MAX_BEACON_BYTES, MAX_NAMED_REFUSED, BeaconsConfig
    from pfdoa.mqtt import client
    from pfdoa.sinks import mcap, web

    def words(name: str) -> str:
        return " ".join((ROOT / "docs" / name).read_text().split())

    fleet, robot, security = words("fleet.md"), words("robot.md"), words("security.md")
    mib = f"{MAX_BEACON_BYTES / 2**20:g} MiB (`beacons.MAX_BEACON_BYTES`"
    idle = f"{transports.DECODER_IDLE_S:g} s (`transports.DECODER_IDLE_S`"
    ahead = f"at most {runner.BUFFERED_AHEAD} reads (`runner.BUFFERED_AHEAD`)"
    for text in (mib, idle, ahead, f"{msgtime.MAX_LEAD_S:g} s (`msgtime.MAX_LEAD_S`)",
                 f"{msgtime.MAX_LAG_S:g} s (`msgtime.MAX_LAG_S`)", f"{msgtime.RESYNC} (`msgtime.RESYNC`)",
                 f"{client.RETRY_LOG_S:g} s (`client.RETRY_LOG_S`)", f"`max_beacons` (default {BeaconsConfig().max_beacons})",
                 f"the first {MAX_NAMED_REFUSED} ids", f"({pipeline.MAX_DECODERS} sources, `pipeline.MAX_DECODERS`)"):
        assert text in fleet, text
    for text in (f"{mcap.CHUNK_MESSAGES:,} messages (`mcap.CHUNK_MESSAGES`)", f"{mcap.FLUSH_S:g} s (`mcap.FLUSH_S`",
                 f"At most {web.MAX_CLIENTS} connections are served at once (`web.MAX_CLIENTS`)",
                 f"two deadlines of {web.TIMEOUT_S:g} s (`web.TIMEOUT_S`)"):
        assert text in robot, text
    for text in (mib, f"{transports.DECODER_IDLE_S:g} s of chunk time (`transports.DECODER_IDLE_S`)", ahead,
                 f"{web.MAX_CLIENTS} (`web.MAX_CLIENTS`)", f"{web.TIMEOUT_S:g} s (`web.TIMEOUT_S`)",
                 f"{msgtime.MAX_LEAD_S:g} s (`msgtime.MAX_LEAD_S`)", f"{msgtime.RESYNC} (`msgtime.RESYNC`)",
                 f"{mcap.CHUNK_MESSAGES:,} messages or {mcap.FLUSH_S:g} s"):
        assert text in security, text
