"""Shared by tests/io/test_anchors_sil.py and tests/qemu/test_qemu_anchors.py (not a test module):
the simulator serving real ports in real time, `pfdoa anchors` against them, and the
check that an anchor's reports moved by exactly the offset it was given.

The check needs no clock: the simulator's trace has every radio reading each anchor's
core was given (``trace.csv``); the reference anchor model (pfdoa.protocol.anchor_model)
folds them into the report each event gives with the configuration the anchors booted
with. A report read before the change equals it; a report read after the change equals
it plus the new offset, 1/256 dB for 1/256 dB (the EMA state is kept across a CONFIG_SET).
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

from pfdoa.gateway.inputs.serial import SerialTransport
from pfdoa.protocol import RssiReport, StreamDecoder, decode_frame, defs
from pfdoa.protocol.anchor_model import AnchorModel
from pfdoa.site import load_site

PY = sys.executable
HANG_S = 120.0  # hang guards only: no assertion depends on how fast anything runs


def start_sim(out_dir: Path, *args: str) -> subprocess.Popen:
    """`pfdoa sim` serving its ports in real time (no gateway), until stopped."""
    cmd = [PY, "-m", "pfdoa", "-q", "sim", "--scenario", "demo", "--realtime", "--speed", "2", "--duration", "600",
           "--seed", "3", "--out-dir", str(out_dir), "--wait", str(HANG_S), *args]
    return subprocess.Popen(cmd, stdout=open(out_dir / "sim.out", "w"), stderr=open(out_dir / "sim.err", "w"))


def wait_for(cond, what: str, proc: subprocess.Popen | None = None):
    end = time.monotonic() + HANG_S
    while True:
        v = cond()
        if v:
            return v
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"the simulator exited ({proc.returncode}) before {what}")
        if time.monotonic() > end:
            raise AssertionError(f"hang guard: no {what} within {HANG_S:g} s")
        time.sleep(0.05)


def stop_sim(proc: subprocess.Popen) -> None:
    """SIGINT: the simulator closes its trace (every reading so far) and its ports."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


# The anchors' replies are waited for this long unless a test gives its own timing: the
# defaults (1 s per try, 3 s for the confirming STATUS) are for real anchors on an idle
# gateway; the simulator's anchors share a loaded CI machine with everything else.
PATIENT = ("--reply-timeout", "5", "--status-timeout", "20", "--timeout", "100")


def anchors_cmd(*args: str) -> tuple[int, object, str]:
    """`pfdoa anchors ... --json`: (exit status, the JSON document, stderr)."""
    timing = () if any(a in args for a in ("--reply-timeout", "--status-timeout", "--timeout")) else PATIENT
    r = subprocess.run([PY, "-m", "pfdoa", "-q", "anchors", *args, *timing, "--json"], capture_output=True,
                       text=True, timeout=HANG_S)
    return r.returncode, json.loads(r.stdout) if r.stdout.strip() else None, r.stderr


def fitted_site(site_path: Path, offsets: dict[int, float], out: Path) -> Path:
    """The site file with these per-anchor rssi_offset_db (as `pfdoa calibrate --out` writes them)."""
    from dataclasses import replace

    from pfdoa.site import site_to_toml

    site = load_site(site_path)
    site = replace(site, anchors=tuple(replace(a, rssi_offset_db=offsets.get(a.id, 0.0)) for a in site.anchors))
    out.write_text(site_to_toml(site))
    return out


def read_reports(ports: list[str], per_anchor: int, anchors) -> list[tuple[int, RssiReport]]:
    """Open the ports, read until every anchor sent ``per_anchor`` reports, close them."""
    transports = [SerialTransport(p, name=f"serial{i}").open() for i, p in enumerate(ports)]
    decoders = [StreamDecoder() for _ in ports]
    got: list[tuple[int, RssiReport]] = []
    count: dict[int, int] = defaultdict(int)
    end = time.monotonic() + HANG_S
    try:
        while not all(count[a] >= per_anchor for a in anchors):
            if time.monotonic() > end:
                raise AssertionError(f"hang guard: reports so far {dict(count)}")
            for t, dec in zip(transports, decoders):
                for chunk in t.read(0.05):
                    for d in dec.feed(chunk.data):
                        if isinstance(d.message, RssiReport):
                            got.append((d.anchor_id, d.message))
                            count[d.anchor_id] += 1
    finally:
        for t in transports:
            t.close()
    return got


def predicted_reports(trace: Path) -> dict[tuple[int, int], int]:
    """(anchor, seq) -> rssi_q8 of that event's report with the boot configuration (no
    offset): the trace's readings through the reference model."""
    models: dict[int, AnchorModel] = {}
    ticks: dict[int, int] = defaultdict(int)
    out: dict[tuple[int, int], int] = {}
    with open(trace, newline="") as fh:
        for row in csv.DictReader(fh):
            a = int(row["anchor"])
            m = models.setdefault(a, AnchorModel(a))
            ticks[a] += 1
            rssi = max(-128, min(127, int(row["rssi_dbm"])))
            for frame in m.reading(ticks[a], int(row["seq"]), rssi, 37, 0, defs.RADIO_BLE):
                d = decode_frame(frame[:-1])
                if isinstance(d.message, RssiReport):
                    out[(a, d.message.seq)] = d.message.rssi_q8
    return out


def check_shift(reports, predicted, offsets_q8: dict[int, int]) -> int:
    """Every report is the predicted one plus its anchor's offset; returns how many were checked."""
    checked = 0
    for a, r in reports:
        want = predicted.get((a, r.seq))
        if want is None:
            continue  # its event's last readings came after the trace was cut
        assert r.rssi_q8 - want == offsets_q8[a], (a, r.seq, r.rssi_q8, want, offsets_q8[a])
        assert bool(r.flags & defs.FLAG_CALIBRATED) == (offsets_q8[a] != 0), (a, r)
        checked += 1
    return checked


def tty_path(p: str) -> str:
    return os.path.realpath(p)
