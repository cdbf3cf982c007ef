"""The simulation loop: beacons -> channel -> emulated anchor cores -> faults -> transport.

One beacon every 1/beacon_hz seconds of simulated time carries a 16-bit sequence number.
Every anchor's radio hears it on the scenario's channels (or misses it); the readings go
into that anchor's core exactly as its radio driver would deliver them, with the anchor's
own drifting millisecond tick; the frames the core emits, each stamped with the simulated
time it was sent, pass the fault injector and go out on the transport: in virtual time a
timed stream (:class:`~pfdoasim.transports.TimedStreamTransport`, as fast as possible), in
real time a port paced at ``speed`` times real time (0 = as fast as possible).

Ground truth is written alongside in the project's trace formats: ``t,anchor,rssi_dbm,
gt_x,gt_y,seq`` (one row per radio reading) and ``.odom.csv`` ``t,dx,dy,dtheta``; and
``.reports.csv`` ``k,seq,anchor,t`` (beacon index, its sequence, anchor): when each report's event closed (the time its tick
stands for), the truth the gateway's event times are scored against.

Other beacons in the site (``Scenario.others``, e.g. an iBeacon): each advertises at its
own times between ours (never within ``POLL_AFTER_S`` of one of ours, so every anchor's
tick only goes forward); every anchor's core matches the advertisement against its filter
table itself (the raw BLE path). The anchors' tables come from their "flash" (set before
they boot, as ``pfdoa anchors filters`` would have left them). Their ground truth is
:attr:`Simulation.other_truth` and ``<trace>.<name>.csv`` (``t,gt_x,gt_y``); their radio
readings are not in ``trace.csv`` (its rows are our beacon's, by seq).

Our authenticated beacon (``Scenario.auth_key``, protocol/SPEC.md 9) and a spoofer
(``Scenario.spoofer``): our beacon's advertisements are built as it sends them (its
counter from ``auth_epoch_ms`` plus the simulated time) and each anchor's core matches and
verifies them itself. The spoofer transmits between ours, through the same room with a
radio noise of its own (its draws never change our beacon's readings), what it captured
of ours (``Spoofer``); the summary counts its receptions by action, and each core's
rejections by reason (``anchor_auth``), which must match them.

Anchors that hear each other (``Scenario.peer_period_ms``): every anchor's core gets a
radio to send its own advertisement on (protocol/SPEC.md 3.5); what the cores sent during
a beacon's step (at their polls) is delivered at the end of that step, ``PEER_AFTER_S``
after the beacon, to every other anchor that hears it (:class:`pfdoasim.peers.PeerLinks`,
the same channel), through the raw entry points; their peer reports go out like the
others. :attr:`Simulation.peer_truth` holds the links' truth (A, n, offsets).
"""

from __future__ import annotations

import csv
import json
import logging
import os
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from pfdoa import signals
from pfdoa.clock import SYSTEM, Clock
from pfdoa.errors import InputError
from pfdoa.odometry import noisy_increments
from pfdoa.outfiles import open_stream, write_whole
from pfdoa.protocol import auth, beacons, defs
from pfdoa.protocol.can import decode_can, is_report_id
from pfdoa.protocol.filters import pack_table
from pfdoa.protocol.messages import RssiReport
from pfdoa.protocol.uart import DecodeError, decode_frame
from pfdoa.radio import PathLoss
from pfdoasim.backends.base import AnchorCore, AnchorFactory, RawReceiver, classify_uart_frames
from pfdoasim.channel import Channel
from pfdoasim.faults import FaultInjector, Frame, drift_factors
from pfdoasim.peers import PeerLinks
from pfdoasim.scenario import CALIBRATION_STREAM, Scenario, Spoofer
from pfdoasim.transports import TimedStreamTransport, Transport

log = logging.getLogger(__name__)

READING_SPACING_S = 0.0004  # BLE advertising: the three channels about 0.4 ms apart
POLL_AFTER_S = 0.021  # poll after the core's 20 ms event timeout so short events close
PEER_AFTER_S = 0.025  # the anchors' advertisements of a beacon's step reach the others this long after it
PEER_STREAM = 0x9EE2  # keys the anchor-to-anchor links' random stream apart from every other use of the seed
RADIO_CODES = {"ble": 0, "zigbee": 1}
# Our beacon's device address when it is not the authenticated one (a random static
# address, the two most significant bits 0b11; on-air order, most significant byte last).
STATIC_ADDRESS = bytes.fromhex("0123456789c5")


@dataclass
class Truth:
    """Ground truth per beacon (index k): time, sequence number, pose."""

    t: list[float] = field(default_factory=list)
    seq: list[int] = field(default_factory=list)
    x: list[float] = field(default_factory=list)
    y: list[float] = field(default_factory=list)
    heading: list[float] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v) for k, v in asdict(self).items()}


def trace_paths(trace_out: str | Path) -> tuple[Path, Path, Path]:
    """(trace.csv, trace.odom.csv, trace.summary.json) for a trace path."""
    p = Path(trace_out)
    stem = p.name[:-4] if p.name.endswith(".csv") else p.name
    return p, p.with_name(stem + ".odom.csv"), p.with_name(stem + ".summary.json")


def reports_path(trace_out: str | Path) -> Path:
    """trace.reports.csv (seq, anchor, true event time of each report) for a trace path."""
    p = Path(trace_out)
    stem = p.name[:-4] if p.name.endswith(".csv") else p.name
    return p.with_name(stem + ".reports.csv")


def _report_seq(f: Frame) -> int | None:
    """The beacon sequence of a report frame the core just built (decoded as the gateway
    would); None when the report is about another beacon than ours (filter entry 0)."""
    d = decode_frame(f.data[:-1]) if f.can_id is None else decode_can(f.can_id, f.data)
    if isinstance(d, DecodeError):  # the core's own output: never, short of a core bug
        raise RuntimeError(f"anchor {f.anchor}: the core sent a report that does not decode ({d})")
    m = d.message
    if not isinstance(m, RssiReport):  # frames are classified as reports before they get here
        raise RuntimeError(f"anchor {f.anchor}: expected a report, the core sent {type(m).__name__}")
    if m.beacon != defs.FILTER_DEFAULT_INDEX or not m.has_seq:
        return None
    return int(m.seq)


def other_truth_path(trace_out: str | Path, name: str) -> Path:
    """<trace>.<beacon name>.csv: t,gt_x,gt_y of another beacon's advertisements."""
    p = Path(trace_out)
    stem = p.name[:-4] if p.name.endswith(".csv") else p.name
    return p.with_name(f"{stem}.{name}.csv")


class Simulation:
    def __init__(
        self,
        scenario: Scenario,
        transport: Transport,
        make_anchor: AnchorFactory,
        speed: float = 10.0,
        trace_out: str | Path | None = None,
        odom_fd: int | None = None,
        clock: Clock = SYSTEM,
    ) -> None:
        self.sc = scenario
        self.clock = clock  # real-time pacing only
        self.transport = transport
        self.make_anchor = make_anchor
        self.speed = speed
        self.trace_out = trace_out
        self.odom_fd = odom_fd  # live odometry (a FIFO the gateway reads), non-blocking
        self.host_epoch = 0.0  # host time of simulated t = 0 (real time: odometry t must be on it)
        self.odom_lines_dropped = 0
        ss = np.random.SeedSequence(scenario.seed)
        # A sixth stream for transport latency: adding jitter changes no other draw; a seventh
        # for a spoofer's radio noise (spawning more children leaves the first ones as they were).
        streams = ss.spawn(7)
        r_chan, r_fault, r_odom, r_drift, r_boot, r_latency = (np.random.default_rng(s) for s in streams[:6])
        r_noise = None
        if scenario.walk:
            # A calibration walk: the same room (walls, offsets, anchor clocks, boot times),
            # a run of its own (readings' noise, faults, odometry, latency).
            ws = np.random.SeedSequence([scenario.seed, CALIBRATION_STREAM, scenario.walk])
            r_noise, r_fault, r_odom, r_latency = (np.random.default_rng(s) for s in ws.spawn(4))
        site = scenario.site
        offsets = site.offsets if scenario.true_offsets is None else scenario.true_offsets
        self.channel = Channel(site.positions, PathLoss.from_site(site), offsets, scenario.channel, r_chan,
                               noise_rng=r_noise, heights=site.heights)
        self.spoof_channel: Channel | None = None
        if scenario.spoofer is not None:
            # The same room (its walls drawn from the same stream), its own noise.
            self.spoof_channel = Channel(site.positions, PathLoss.from_site(site), offsets, scenario.channel,
                                         np.random.default_rng(streams[0]), noise_rng=np.random.default_rng(streams[6]),
                                         heights=site.heights)
        if scenario.raw_beacon and scenario.radio != "ble":
            raise InputError(f"scenario {scenario.name}: the authenticated beacon and the spoofer are BLE only here")
        self._sent: deque[tuple[int, bytes, bytes]] = deque()  # our advertisements: (k, AdvA, AdvData)
        self._auth_ids: tuple[int, auth.Ids] | None = None
        self.spoofed: dict[str, dict[str, int]] = {"transmissions": {}, "receptions": {}}
        # Anchor-to-anchor links: their readings' noise a stream of their own (per walk), so
        # advertising anchors leave the beacon's readings as they were.
        self.peers: PeerLinks | None = None
        self._peer_frames: list[tuple[int, int, bytes]] = []  # (anchor index, radio, frame) not yet delivered
        self.peer_counts = {"sent": 0, "heard": 0, "missed": 0}
        if scenario.peer_period_ms:
            r_peer = np.random.default_rng([scenario.seed, PEER_STREAM, scenario.walk])
            self.peers = PeerLinks(self.channel, site, offsets, scenario.true_tx_offsets, r_peer)
        self.injector = FaultInjector(scenario.faults, r_fault, can=transport.is_can)
        self.r_odom = r_odom
        self.ids = site.anchor_ids
        self.drift = drift_factors(self.ids, scenario.faults.drift_ppm, r_drift, scenario.faults.skew)
        if isinstance(transport, TimedStreamTransport):
            transport.rng = r_latency
        self.report_times: list[tuple[int, int, float]] = []  # (beacon index, anchor, sent at), every report
        self._k = 0
        # Anchors boot at different moments: their ticks start anywhere.
        self.boot_ms = {a: int(r_boot.integers(0, 2**32)) for a in self.ids}
        self.cores: dict[int, AnchorCore | None] = {}
        self.truth = Truth()
        self.other_truth = {b.name: Truth() for b in scenario.others}  # their t, x, y (seq unused)
        self.radio_counts = {"readings": 0, "multipath": 0, "missed": 0}
        self.beacons = 0
        self.stopped = False

    # -- anchor time -------------------------------------------------------------------
    def tick(self, anchor: int, t: float) -> int:
        return int(self.boot_ms[anchor] + t * 1000.0 * self.drift[anchor]) & 0xFFFFFFFF

    def _store_filter_tables(self) -> None:
        """Other beacons: the anchors' flash holds the scenario's filter table before they boot."""
        table = self.sc.filter_table()
        if table is None:
            return
        flash = getattr(self.make_anchor, "filter_flash", None)
        if flash is None:
            raise InputError(f"scenario {self.sc.name}: its anchors match other beacons themselves, which this "
                             "anchor backend cannot (use --anchor-backend c, mpy or qemu)")
        for a in self.ids:
            flash.setdefault(a, pack_table(table))

    def _other_transmissions(self, tb: np.ndarray) -> list[tuple[float, int]]:
        """(time, index into sc.others; -1: the spoofer) of every other transmission, in time
        order; each must fall at least POLL_AFTER_S after one of ours and end before the next."""
        out = sorted((float(t), i) for i, b in enumerate(self.sc.others) for t in b.times(self.sc.duration_s))
        sp = self.sc.spoofer
        if sp is not None:
            out = sorted(out + [(float(t) + phase, -1 - i) for t in tb for i, (_, _, phase) in enumerate(sp.actions)])
        if out and tb.size:
            t = np.array([x[0] for x in out])
            prev = tb[np.clip(np.searchsorted(tb, t, side="right") - 1, 0, None)]
            nxt = np.append(tb, np.inf)[np.searchsorted(tb, t, side="right")]
            if np.any(t - prev < POLL_AFTER_S) or np.any(t + POLL_AFTER_S >= nxt):
                raise InputError(f"scenario {self.sc.name}: another beacon advertises within {POLL_AFTER_S * 1e3:g} ms "
                                 "of ours (the anchors' ticks would go back)")
        return out

    def _give_peer_radios(self) -> None:
        """Anchors that hear each other: every core gets a radio of the scenario's kind."""
        if self.peers is None:
            return
        if not hasattr(self.make_anchor, "peer_radio"):
            raise InputError(f"scenario {self.sc.name}: its anchors send their own advertisements, which this "
                             "anchor backend cannot (use --anchor-backend c, mpy or qemu)")
        radio = RADIO_CODES[self.sc.radio]
        if getattr(self.make_anchor, "peer_radio", None) not in (None, radio):
            raise InputError(f"scenario {self.sc.name}: these anchors advertise on another radio than the beacon's")
        self.make_anchor.peer_radio = radio  # the backends' factories have it (checked above)

    @property
    def peer_truth(self) -> dict | None:
        """What the links follow (anchor ids in site order): the room's A and n, the anchors'
        receive and transmit offsets (dB); None when the anchors do not advertise."""
        if self.peers is None:
            return None
        n = len(self.ids)
        rx = self.channel.offsets if self.channel.offsets is not None else np.zeros(n)
        tx = self.sc.true_tx_offsets if self.sc.true_tx_offsets is not None else np.zeros(n)
        return {"anchors": list(self.ids), "rssi_at_1m_dbm": self.channel.model.rssi_at_1m_dbm,
                "path_loss_exponent": self.channel.model.path_loss_exponent,
                "rx_offsets_db": [float(v) for v in rx], "tx_offsets_db": [float(v) for v in tx]}

    def _take_peer_frames(self, index: int, core: AnchorCore) -> None:
        for radio, frame in core.take_radio():
            self._peer_frames.append((index, radio, frame))

    def _deliver_peers(self, t: float, chans: np.ndarray) -> list[Frame]:
        """Every advertisement sent in this step, to every other anchor that hears it at
        ``t`` (+ the channels' spacing); the frames the receivers send, after the link faults."""
        if self.peers is None or not self._peer_frames:
            return []
        sent, self._peer_frames = self._peer_frames, []
        inj = self.injector
        out: list[Frame] = []
        for j, radio, frame in sent:
            self.peer_counts["sent"] += 1
            readings, _ = self.peers.sample(j, chans)
            for i, a in enumerate(self.ids):
                core = self.cores.get(a)
                if i == j or core is None:
                    continue
                if not isinstance(core, RawReceiver):
                    raise InputError("anchors that hear each other need a backend that matches raw frames")
                silent = inj.silenced(a, t)
                frames: list[Frame] = []
                for k, ch in enumerate(chans):
                    r = readings[i, k]
                    if np.isnan(r):
                        self.peer_counts["missed"] += 1
                        continue
                    self.peer_counts["heard"] += 1
                    tk = t + k * READING_SPACING_S
                    if radio == defs.RADIO_BLE:
                        core.ble_pdu(frame, int(r), int(ch), self.tick(a, tk))
                    else:
                        core.ieee802154(frame, int(r), int(ch), 0, self.tick(a, tk))
                    frames += self._frames(a, core, tk)
                self._take_peer_frames(i, core)  # a QEMU anchor polls itself at each injection
                for f in frames:
                    if silent:
                        inj.count_silenced(f)
                    else:
                        out += inj.apply(f)
        return out

    def _boot(self, anchor: int, t: float) -> AnchorCore:
        core = self.make_anchor(anchor, self.transport.is_can, self.sc.anchor, self.tick(anchor, t))
        self.cores[anchor] = core
        return core

    def _frames(self, anchor: int, core: AnchorCore, t: float) -> list[Frame]:
        """What the core has sent since the last call, stamped as sent at simulated time t."""
        if self.transport.is_can:
            out = [Frame(anchor, data, is_report_id(can_id), can_id, t) for can_id, data in core.take_can()]
        else:
            out = [Frame(anchor, data, is_report, None, t) for data, is_report in classify_uart_frames(core.take_uart())]
        for f in out:
            if f.is_report:
                seq = _report_seq(f)
                if seq is None:
                    continue  # about another beacon: its event times are not scored
                k = self._k - ((self._k - seq) & 0xFFFF)  # the beacon it reports (this one or earlier)
                self.report_times.append((k, anchor, t))
        return out

    # -- main loop ---------------------------------------------------------------------
    def run(self, on_beacon: Callable[[int, float], None] | None = None) -> dict:
        sc, inj, tr = self.sc, self.injector, self.transport
        radio = RADIO_CODES[sc.radio]
        chans = sc.channels
        n_beacons = int(np.floor(sc.duration_s * sc.beacon_hz + 1e-9)) + 1
        tb = np.arange(n_beacons) / sc.beacon_hz
        poses = np.array([sc.pose_at(t) for t in tb]).reshape(-1, 3)
        # The robot's wheel odometry between consecutive beacons (noisy, robot frame).
        self.odometry = noisy_increments(np.column_stack([tb, poses]), sc.odometry, self.r_odom)
        others = self._other_transmissions(tb)
        next_other = 0
        self._store_filter_tables()
        self._give_peer_radios()
        for a in self.ids:
            self._boot(a, 0.0)
        stop = signals.active()
        writer = trace_file = None
        if self.trace_out:
            trace_path = trace_paths(self.trace_out)[0]
            trace_path.parent.mkdir(parents=True, exist_ok=True)
            trace_file = open_stream(str(trace_path), "the trace")[0]
            writer = csv.writer(trace_file)
            writer.writerow(["t", "anchor", "rssi_dbm", "gt_x", "gt_y", "seq"])
        port_up = True
        wall0 = self.clock.monotonic()
        if self.speed and self.speed > 0 and self.odom_fd is not None:
            self.host_epoch = self.clock.now()
        try:
            for k in range(n_beacons + 1):
                # Other beacons' advertisements before this one of ours (or the end).
                until = float(tb[k]) if k < n_beacons else np.inf
                while next_other < len(others) and others[next_other][0] < until and not self.stopped:
                    t_o, i_o = others[next_other]
                    if i_o < 0:
                        port_up = self._spoof(t_o, -1 - i_o, port_up, chans, wall0)
                    else:
                        port_up = self._other_beacon(t_o, i_o, port_up, radio, chans, wall0)
                    next_other += 1
                if self.stopped or k == n_beacons:
                    break
                if stop.stopped:  # SIGINT/SIGTERM (pfdoa.signals): the beacons so far are the run
                    self.stopped = True
                    break
                t = float(tb[k])
                seq = k & 0xFFFF
                self._k = k
                x, y, h = poses[k]
                self.truth.t.append(t)
                self.truth.seq.append(seq)
                self.truth.x.append(float(x))
                self.truth.y.append(float(y))
                self.truth.heading.append(float(h))
                tr.advance(t)
                readings, counts = self.channel.sample(np.array([x, y]), chans)
                for key, v in counts.items():
                    self.radio_counts[key] += v
                out = self._anchors_hear(seq, t, x, y, readings, chans, radio, writer)
                out += self._deliver_peers(t + PEER_AFTER_S, chans)
                # The serial port disappears / comes back.
                down = inj.port_down(t)
                if down == port_up:
                    port_up = not down
                    tr.set_port_up(port_up)
                    if down:
                        inj.counts.port_drops += 1
                self._pace(wall0, t)
                self._live_odometry(k)
                if not port_up:
                    inj.count_port_down(out)
                elif out and not tr.has_reader():
                    # The port is back but the gateway has not reopened it yet: the bytes
                    # go nowhere (a pty reader's open flushes them), however long that takes.
                    inj.count_unread(out)
                else:
                    failed = tr.send(out)
                    if failed:
                        inj.count_port_down(out[-failed:])
                    self._host_to_anchors(t)
                self.beacons += 1
                if on_beacon:
                    on_beacon(k, t)
            rest = inj.flush()
            if port_up and rest:
                tr.send(rest)
        finally:
            if trace_file:
                trace_file.close()
        summary = self.summary()
        if self.trace_out:
            self._write_odometry(self.trace_out)
            self._write_report_times(self.trace_out)
            self._write_other_truth(self.trace_out)
            write_whole(trace_paths(self.trace_out)[2], json.dumps(summary, indent=1) + "\n", "the trace's summary")
        return summary

    def _anchors_hear(self, seq: int, t: float, x: float, y: float, readings: np.ndarray, chans: np.ndarray,
                      radio: int, writer) -> list[Frame]:
        """Every anchor's radio delivers its readings of one beacon to its core; returns the
        frames that leave the anchors (after the link faults), in anchor order."""
        inj = self.injector
        out: list[Frame] = []
        adv = self._advertisement(seq, t) if self.sc.raw_beacon else None
        for i, a in enumerate(self.ids):
            silent = inj.silenced(a, t)
            core = self.cores.get(a)
            if self.sc.faults.reboot and silent:
                # Powered off: hears nothing, says nothing; boots afresh afterwards.
                self.cores[a] = None
                continue
            if core is None:
                # Power is back: the MCU's tick counter restarts from zero.
                self.boot_ms[a] = -int(t * 1000.0 * self.drift[a])
                core = self._boot(a, t)
                inj.counts.reboots += 1
            sent: list[Frame] = []
            for j, ch in enumerate(chans):
                r = readings[i, j]
                if np.isnan(r):
                    continue  # the radio missed it
                tj = t + j * READING_SPACING_S
                if adv is None:
                    core.radio(seq, int(r), int(ch), 0, radio, self.tick(a, tj))
                else:
                    self._raw_core(core).ble_adv(adv[0], adv[1], int(r), int(ch), self.tick(a, tj))
                sent += self._frames(a, core, tj)  # an event closed by this reading is sent now
                if writer:
                    writer.writerow([f"{t:.4f}", a, int(r), f"{x:.4f}", f"{y:.4f}", seq])
            core.poll(self.tick(a, t + POLL_AFTER_S))
            sent += self._frames(a, core, t + POLL_AFTER_S)
            self._take_peer_frames(i, core)
            for f in sent:
                if silent:
                    inj.count_silenced(f)  # the link is cut; the anchor runs on
                else:
                    out += inj.apply(f)
        return out

    def _other_beacon(self, t: float, i: int, port_up: bool, radio: int, chans: np.ndarray, wall0: float) -> bool:
        """One advertisement of another beacon: every anchor that hears it matches it itself;
        the frames go out like ours (link faults, the port's state). Returns port_up."""
        b, tr = self.sc.others[i], self.transport
        x, y = b.pose_at(t)
        truth = self.other_truth[b.name]
        truth.t.append(t)
        truth.x.append(float(x))
        truth.y.append(float(y))
        tr.advance(t)
        readings, counts = self.channel.sample(np.array([x, y]), chans)
        for key, v in counts.items():
            self.radio_counts[key] += v
        out, _ = self._others_heard(t, readings, chans, (b.adv_a, b.adv_data))
        return self._deliver(out, port_up, wall0, t)

    def _others_heard(self, t: float, readings: np.ndarray, chans: np.ndarray,
                      adv: tuple[bytes, bytes]) -> tuple[list[Frame], int]:
        """An advertisement (AdvA, AdvData) of another transmitter than our beacon (another
        beacon, the spoofer): every powered anchor whose radio heard it matches it itself.
        The frames that leave the anchors (after the link faults), and the receptions."""
        inj = self.injector
        out: list[Frame] = []
        heard = 0
        for ia, a in enumerate(self.ids):
            core = self.cores.get(a)
            if core is None:
                continue  # powered off (the reboot fault)
            silent = inj.silenced(a, t)
            sent: list[Frame] = []
            for j, ch in enumerate(chans):
                r = readings[ia, j]
                if np.isnan(r):
                    continue
                tj = t + j * READING_SPACING_S
                self._raw_core(core).ble_adv(adv[0], adv[1], int(r), int(ch), self.tick(a, tj))
                heard += 1
                sent += self._frames(a, core, tj)
            core.poll(self.tick(a, t + POLL_AFTER_S))
            sent += self._frames(a, core, t + POLL_AFTER_S)
            for f in sent:
                if silent:
                    inj.count_silenced(f)
                else:
                    out += inj.apply(f)
        return out, heard

    def _deliver(self, out: list[Frame], port_up: bool, wall0: float, t: float) -> bool:
        """The frames of another transmitter's advertisement to the gateway, as ours go
        (the port's state, a reader). Returns port_up."""
        inj, tr = self.injector, self.transport
        self._pace(wall0, t)
        if not port_up:
            inj.count_port_down(out)
        elif out and not tr.has_reader():
            inj.count_unread(out)
        else:
            failed = tr.send(out)
            if failed:
                inj.count_port_down(out[-failed:])
        return port_up

    def _raw_core(self, core: AnchorCore) -> RawReceiver:
        if not isinstance(core, RawReceiver):  # py-mean: no beacon filter table
            raise InputError(f"the {self.sc.name} scenario needs anchors that match raw advertisements "
                             "(--anchor-backend c, mpy or qemu)")
        return core

    def _advertisement(self, seq: int, t: float) -> tuple[bytes, bytes]:
        """(AdvA, AdvData) of our beacon's advertisement with this seq at simulated time t
        (the authenticated one's from its key and counter), remembered for the spoofer."""
        key = self.sc.auth_key
        if key is None:
            adv = (STATIC_ADDRESS, beacons.pfdoa_adv_data(seq, defs.FILTER_DEFAULT_ID))
        else:
            counter = auth.counter_at(self.sc.auth_epoch_ms + int(round(t * 1000.0)))
            if self._auth_ids is None or self._auth_ids[0] != counter:
                self._auth_ids = (counter, auth.derive(key, counter))  # once a period, as the beacon
            adv = (self._auth_ids[1].adv_a, beacons.pfdoa_auth_adv_data(key, counter, seq))
        if self.sc.spoofer is not None:
            self._sent.append((self._k, *adv))
            horizon = max(d for _, d, _ in self.sc.spoofer.actions) * self.sc.beacon_hz + 2
            while self._sent and self._sent[0][0] < self._k - horizon:
                self._sent.popleft()
        return adv

    def _spoofed(self, action: tuple[str, float, float]) -> tuple[bytes, bytes] | None:
        """What the spoofer sends for one action, or None (nothing captured that long ago)."""
        kind, delay, _ = action
        want = self._k - int(round(delay * self.sc.beacon_hz))
        found = next((x for x in reversed(self._sent) if x[0] == want), None)
        if found is None:
            return None
        _, adv_a, data = found
        if kind == "replay":
            return adv_a, data
        # A forgery: the latest advertisement with the next sequence number in it. Ours:
        # seq (LE) after 'P' 'F'; the authenticated one: eseq after 'P' 'A' and the counter.
        d = bytearray(data)
        if self.sc.auth_key is None:
            seq = d[9] | (d[10] << 8)
            d[9:11] = ((seq + 1) & 0xFFFF).to_bytes(2, "little")
        else:
            seq = self._k & 0xFFFF
            flip = seq ^ ((seq + 1) & 0xFFFF)  # eseq = seq ^ pad: the next seq under the same pad
            d[13] ^= flip & 0xFF
            d[14] ^= flip >> 8
        return adv_a, bytes(d)

    def _spoof(self, t: float, i: int, port_up: bool, chans: np.ndarray, wall0: float) -> bool:
        """One transmission (action i) of the spoofer (Scenario.spoofer), heard by the anchors
        through the same room, gain_db louder than our beacon at its place. Returns port_up."""
        sp, tr = self.sc.spoofer, self.transport
        assert sp is not None and self.spoof_channel is not None
        action = sp.actions[i]
        frame = self._spoofed(action)
        if frame is None:
            return port_up
        label = Spoofer.label(action)
        sent = self.spoofed["transmissions"]
        sent[label] = sent.get(label, 0) + 1
        tr.advance(t)
        readings, _ = self.spoof_channel.sample(np.array([sp.x, sp.y]), chans)
        readings = np.minimum(readings + sp.gain_db, self.sc.channel.ceil_dbm)
        out, heard = self._others_heard(t, readings, chans, frame)
        rec = self.spoofed["receptions"]
        rec[label] = rec.get(label, 0) + heard
        return self._deliver(out, port_up, wall0, t)

    def _pace(self, wall0: float, t: float) -> None:
        if self.speed and self.speed > 0:
            wait = wall0 + t / self.speed - self.clock.monotonic()
            if wait > 0:
                self.clock.sleep(wait)

    def _live_odometry(self, k: int) -> None:
        t, dx, dy, dth = self.odometry[k]
        if self.transport.odometry(float(t), float(dx), float(dy), float(dth)) or self.odom_fd is None:
            return
        # A live gateway stamps sets with its host clock: so must the odometry be.
        th = self.host_epoch + t / self.speed if self.speed and self.speed > 0 else t
        try:
            os.write(self.odom_fd, f"{th:.6f},{dx:.5f},{dy:.5f},{dth:.6f}\n".encode())
        except (BlockingIOError, BrokenPipeError):
            self.odom_lines_dropped += 1  # the reader fell behind or went away

    def _host_to_anchors(self, t: float) -> None:
        """What the host sends reaches every anchor on the shared line or bus (each core
        decides whether a frame is addressed to it), as on a multi-drop UART or CAN."""
        tr = self.transport
        if tr.is_can:
            frames = tr.poll_can_rx()
            for a, core in self.cores.items():
                if core is not None and frames:
                    for can_id, data in frames:
                        core.can_rx(can_id, data)
                    core.poll(self.tick(a, t))
            return
        data = tr.poll_rx()
        if data:
            for a, core in self.cores.items():
                if core is not None:
                    core.uart_rx(data, self.tick(a, t))

    def _write_report_times(self, trace_out: str | Path) -> None:
        with open_stream(str(reports_path(trace_out)), "the report times")[0] as fh:
            w = csv.writer(fh)
            w.writerow(["k", "seq", "anchor", "t"])
            for k, a, t in self.report_times:
                w.writerow([k, k & 0xFFFF, a, repr(t)])

    def _write_other_truth(self, trace_out: str | Path) -> None:
        for name, truth in self.other_truth.items():
            with open_stream(str(other_truth_path(trace_out, name)), "a beacon's truth")[0] as fh:
                w = csv.writer(fh)
                w.writerow(["t", "gt_x", "gt_y"])
                for t, x, y in zip(truth.t, truth.x, truth.y):
                    w.writerow([repr(t), f"{x:.4f}", f"{y:.4f}"])

    def _write_odometry(self, trace_out: str | Path) -> None:
        inc = self.odometry[: self.beacons]
        path = trace_paths(trace_out)[1]
        with open_stream(str(path), "the odometry")[0] as fh:
            w = csv.writer(fh)
            w.writerow(["t", "dx", "dy", "dtheta"])
            for t, dx, dy, dth in inc:
                w.writerow([f"{t:.4f}", f"{dx:.5f}", f"{dy:.5f}", f"{dth:.6f}"])

    def summary(self) -> dict:
        sc = self.sc
        return {
            "scenario": sc.name,
            "seed": sc.seed,
            "transport": self.transport.name,
            "beacons": self.beacons,
            "beacon_hz": sc.beacon_hz,
            "duration_s": self.beacons / sc.beacon_hz,
            "anchors": list(self.ids),
            "radio": {**self.radio_counts, "kind": sc.radio, "channels": [int(c) for c in sc.channels]},
            "channel": asdict(sc.channel),
            "drift_ppm": {str(a): round((f - 1.0) * 1e6, 3) for a, f in self.drift.items()},
            "faults": self.injector.counts.as_dict(),
            "odometry_lines_dropped": self.odom_lines_dropped,
            **({"other_beacons": {n: len(tr.t) for n, tr in self.other_truth.items()}} if self.other_truth else {}),
            **({"spoofer": self.spoofed} if sc.spoofer is not None else {}),
            **({"anchor_auth": {str(a): c.auth_rejected() for a, c in self.cores.items()
                                if c is not None and hasattr(c, "auth_rejected")}} if sc.auth_key is not None else {}),
            **({"peers": {**self.peer_counts, "period_ms": sc.peer_period_ms}} if self.peers is not None else {}),
        }
