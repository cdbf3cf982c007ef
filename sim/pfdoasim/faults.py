"""Fault injection on the anchor-to-gateway link, with every fault counted.

Faults act on whole link frames (a COBS frame with its delimiter on UART, one CAN frame
on CAN), per anchor stream, in send order:

* ``loss``      probability that a frame is dropped
* ``dup``       probability that a frame is sent twice
* ``reorder``   probability that a frame is held back and sent after the stream's next frame
* ``ber``       bit-error rate on UART bytes (each bit flips independently); on CAN the
                controller's CRC-15 and automatic retransmission hide bit errors, so it
                only counts the retransmissions
* ``silence``   anchor A is silent from S for D seconds (``A@S+D``); with ``reboot`` it comes
                back as a freshly booted anchor (uptime and filter state reset)
* ``drift_ppm`` anchor tick rate error: each anchor gets a fixed error drawn from N(0, ppm)
* ``skew``      anchor A's tick rate error is exactly PPM (``A@PPM``, may be negative;
                overrides ``drift_ppm`` for that anchor)
* ``portdrop``  the serial port disappears from S for D seconds (``S+D``): in real time the
                pty is closed and re-created behind the same symlink, like a USB adapter
                unplugged; in virtual time the frames sent meanwhile are lost (counted)

Transport latency (virtual time, :class:`pfdoasim.transports.TimedStreamTransport`): a frame
arrives at the gateway when it was sent plus

* ``jitter``    0..MS milliseconds, uniform, per frame (a byte stream stays in order: a frame
                never arrives before the one sent before it on the same port)
* ``batch``     a USB adapter that hands frames over every MS milliseconds (arrival rounded
                up to the next multiple)
* ``stall``     nothing is delivered from S for D seconds (``S+D``), then everything at once
                (a scheduler stall, a hub that hangs)

Spec string for the command line: ``loss=0.02,dup=0.01,reorder=0.01,ber=1e-5,
silence=2@10+5,drift_ppm=100,portdrop=20+2,reboot=1,jitter=50,skew=1@-100`` (``silence``,
``portdrop``, ``stall`` and ``skew`` may repeat).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import asdict, dataclass, field

import numpy as np

from pfdoa.errors import InputError


@dataclass(frozen=True)
class Silence:
    anchor: int
    start_s: float
    duration_s: float

    def active(self, anchor: int, t: float) -> bool:
        return anchor == self.anchor and self.start_s <= t < self.start_s + self.duration_s


@dataclass(frozen=True)
class PortDrop:
    start_s: float
    duration_s: float


@dataclass(frozen=True)
class Stall:
    start_s: float
    duration_s: float


@dataclass(frozen=True)
class FaultConfig:
    loss: float = 0.0
    dup: float = 0.0
    reorder: float = 0.0
    ber: float = 0.0
    drift_ppm: float = 0.0
    reboot: bool = False
    silence: tuple[Silence, ...] = ()
    portdrop: tuple[PortDrop, ...] = ()
    jitter_ms: float = 0.0
    batch_ms: float = 0.0
    stall: tuple[Stall, ...] = ()
    skew: tuple[tuple[int, float], ...] = ()  # (anchor, ppm)

    @property
    def any(self) -> bool:
        return any((self.loss, self.dup, self.reorder, self.ber, self.drift_ppm, self.silence, self.portdrop,
                    self.jitter_ms, self.batch_ms, self.stall, self.skew))

    @property
    def link(self) -> bool:
        """Faults that act on the frames between the anchors and the gateway."""
        return any((self.loss, self.dup, self.reorder, self.ber, self.portdrop))

    @property
    def latency(self) -> bool:
        return any((self.jitter_ms, self.batch_ms, self.stall))


def _span(text: str, key: str) -> tuple[float, float]:
    try:
        s, d = text.split("+", 1)
        start, dur = float(s), float(d)
    except ValueError:
        raise InputError(f"--faults {key}: expected START+DURATION seconds, got {text!r}") from None
    if start < 0 or dur <= 0:
        raise InputError(f"--faults {key}: start must be >= 0 and duration > 0, got {text!r}")
    return start, dur


def parse_faults(spec: str | None) -> FaultConfig:
    """Parse ``key=value,...`` (see the module doc); raises :class:`InputError`."""
    if not spec:
        return FaultConfig()
    probs: dict[str, float] = {}
    silences: list[Silence] = []
    drops: list[PortDrop] = []
    stalls: list[Stall] = []
    skews: dict[int, float] = {}
    latency: dict[str, float] = {}
    drift = 0.0
    reboot = False
    for item in spec.split(","):
        item = item.strip()
        if not item:
            continue
        key, sep, value = item.partition("=")
        key = key.strip().replace("-", "_")
        if not sep:
            raise InputError(f"--faults: expected key=value, got {item!r}")
        if key in ("loss", "dup", "reorder", "ber"):
            try:
                v = float(value)
            except ValueError:
                raise InputError(f"--faults {key}: not a number: {value!r}") from None
            if not 0.0 <= v <= 1.0:
                raise InputError(f"--faults {key}: must be in [0, 1], got {v}")
            probs[key] = v
        elif key == "drift_ppm":
            try:
                drift = float(value)
            except ValueError:
                raise InputError(f"--faults drift_ppm: not a number: {value!r}") from None
            if not 0.0 <= drift <= 100_000:
                raise InputError(f"--faults drift_ppm: must be in [0, 100000], got {drift}")
        elif key == "reboot":
            reboot = value.strip().lower() in ("1", "true", "yes", "on")
        elif key == "silence":
            anchor, at, span = value.partition("@")
            if not at:
                raise InputError(f"--faults silence: expected ANCHOR@START+DURATION, got {value!r}")
            try:
                aid = int(anchor)
            except ValueError:
                raise InputError(f"--faults silence: anchor id not an integer: {anchor!r}") from None
            silences.append(Silence(aid, *_span(span, key)))
        elif key == "portdrop":
            drops.append(PortDrop(*_span(value, key)))
        elif key == "stall":
            stalls.append(Stall(*_span(value, key)))
        elif key in ("jitter", "batch"):
            try:
                ms = float(value)
            except ValueError:
                raise InputError(f"--faults {key}: not a number of milliseconds: {value!r}") from None
            if not 0.0 <= ms <= 10_000:
                raise InputError(f"--faults {key}: must be in [0, 10000] ms, got {ms}")
            latency[f"{key}_ms"] = ms
        elif key == "skew":
            anchor, at, ppm = value.partition("@")
            try:
                aid, v = int(anchor), float(ppm)
            except ValueError:
                raise InputError(f"--faults skew: expected ANCHOR@PPM, got {value!r}") from None
            if not at or not -100_000 <= v <= 100_000:
                raise InputError(f"--faults skew: expected ANCHOR@PPM with PPM in [-100000, 100000], got {value!r}")
            skews[aid] = v
        else:
            raise InputError(f"--faults: unknown fault {key!r} (known: loss, dup, reorder, ber, drift_ppm, skew, "
                             "reboot, silence, portdrop, jitter, batch, stall)")
    return FaultConfig(drift_ppm=drift, reboot=reboot, silence=tuple(silences), portdrop=tuple(drops),
                       stall=tuple(stalls), skew=tuple(sorted(skews.items())), **latency, **probs)


@dataclass
class LinkCounts:
    """What happened to one anchor's frames between its core and the gateway."""

    frames: int = 0  # produced by the anchor core
    reports: int = 0  # RSSI_REPORT frames among them
    sent: int = 0  # written to the transport (duplicates included)
    dropped: int = 0  # random loss
    dropped_reports: int = 0
    duplicated: int = 0
    duplicated_reports: int = 0
    reordered: int = 0  # frames overtaken by the stream's next frame
    corrupted: int = 0  # frames with at least one flipped bit
    corrupted_reports: int = 0
    bit_flips: int = 0
    retransmits: int = 0  # CAN: bit errors repaired by retransmission
    silenced: int = 0  # frames lost while the anchor was silent
    silenced_reports: int = 0
    port_down: int = 0  # frames lost while the serial port was gone
    port_down_reports: int = 0
    unread: int = 0  # frames lost while the port was there but nobody had it open
    unread_reports: int = 0


@dataclass
class FaultCounts:
    per_anchor: dict[int, LinkCounts] = field(default_factory=lambda: defaultdict(LinkCounts))
    port_drops: int = 0
    reboots: int = 0

    def total(self) -> LinkCounts:
        tot = LinkCounts()
        for c in self.per_anchor.values():
            for k, v in asdict(c).items():
                setattr(tot, k, getattr(tot, k) + v)
        return tot

    def as_dict(self) -> dict:
        return {
            "per_anchor": {str(a): asdict(c) for a, c in sorted(self.per_anchor.items())},
            "total": asdict(self.total()),
            "port_drops": self.port_drops,
            "reboots": self.reboots,
        }


@dataclass
class Frame:
    anchor: int
    data: bytes  # UART: COBS frame incl. delimiter; CAN: payload
    is_report: bool
    can_id: int | None = None
    t: float = 0.0  # simulated time the anchor sent it (for a report: when its event closed)


class FaultInjector:
    """Applies a :class:`FaultConfig` to frames, per anchor stream, with a seeded RNG."""

    def __init__(self, config: FaultConfig, rng: np.random.Generator, can: bool = False) -> None:
        self.config = config
        self.rng = rng
        self.can = can
        self.counts = FaultCounts()
        self._held: dict[int, Frame] = {}

    def silenced(self, anchor: int, t: float) -> bool:
        return any(s.active(anchor, t) for s in self.config.silence)

    def port_down(self, t: float) -> bool:
        return any(d.start_s <= t < d.start_s + d.duration_s for d in self.config.portdrop)

    def count_produced(self, frame: Frame) -> LinkCounts:
        c = self.counts.per_anchor[frame.anchor]
        c.frames += 1
        c.reports += frame.is_report
        return c

    def count_silenced(self, frame: Frame) -> None:
        c = self.count_produced(frame)
        c.silenced += 1
        c.silenced_reports += frame.is_report

    def count_port_down(self, frames: list[Frame]) -> None:
        for f in frames:
            c = self.counts.per_anchor[f.anchor]
            c.port_down += 1
            c.port_down_reports += f.is_report
            c.sent -= 1  # they were counted as sent by apply()

    def count_unread(self, frames: list[Frame]) -> None:
        for f in frames:
            c = self.counts.per_anchor[f.anchor]
            c.unread += 1
            c.unread_reports += f.is_report
            c.sent -= 1  # they were counted as sent by apply()

    def apply(self, frame: Frame) -> list[Frame]:
        """Frames to put on the wire (0, 1 or 2 of them, possibly an earlier held one)."""
        cfg, rng = self.config, self.rng
        c = self.count_produced(frame)
        if cfg.loss and rng.random() < cfg.loss:
            c.dropped += 1
            c.dropped_reports += frame.is_report
            return self._release_held(frame.anchor, [])
        if cfg.ber:
            frame = self._corrupt(frame, c)
        out = [frame]
        if cfg.dup and rng.random() < cfg.dup:
            c.duplicated += 1
            c.duplicated_reports += frame.is_report
            out.append(frame)
        if cfg.reorder and frame.anchor not in self._held and rng.random() < cfg.reorder:
            self._held[frame.anchor] = out.pop(0)
            c.sent += len(out)
            return out
        out = self._release_held(frame.anchor, out)
        return out

    def _release_held(self, anchor: int, out: list[Frame]) -> list[Frame]:
        held = self._held.pop(anchor, None)
        if held is not None:
            # Counted as reordered only if a later frame really overtook it.
            self.counts.per_anchor[anchor].reordered += bool(out)
            out = out + [held]
        self.counts.per_anchor[anchor].sent += len(out)
        return out

    def flush(self) -> list[Frame]:
        """Frames still held back (at the end of a run)."""
        out = []
        for anchor in list(self._held):
            out += self._release_held(anchor, [])
        return out

    def _corrupt(self, frame: Frame, c: LinkCounts) -> Frame:
        nbits = 8 * len(frame.data) + (11 + 4 + 15 if self.can else 0)
        flips = self.rng.random(nbits) < self.config.ber
        k = int(flips.sum())
        if k == 0:
            return frame
        if self.can:
            c.retransmits += 1
            return frame
        c.corrupted += 1
        c.corrupted_reports += frame.is_report
        c.bit_flips += k
        mask = np.packbits(flips).tobytes()
        data = bytes(a ^ b for a, b in zip(frame.data, mask))
        return Frame(frame.anchor, data, frame.is_report, frame.can_id, frame.t)


def drift_factors(anchor_ids: tuple[int, ...], ppm: float, rng: np.random.Generator,
                  skew: tuple[tuple[int, float], ...] = ()) -> dict[int, float]:
    """Tick-rate factor per anchor (1 + error), errors drawn from N(0, ppm) parts per million,
    or exactly ``skew``'s ppm for the anchors it names."""
    out = {a: 1.0 + (float(rng.normal(0.0, ppm)) * 1e-6 if ppm else 0.0) for a in anchor_ids}
    for a, v in skew:
        if a in out:
            out[a] = 1.0 + v * 1e-6
    return out
