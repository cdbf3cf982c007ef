"""``udp:[HOST:]PORT``: anchors that send their frames as UDP datagrams (Wi-Fi anchors: ESP32s).

A datagram carries bytes of the anchor's UART stream (protocol/SPEC.md 2.5): one or more
COBS frames, each with its 0x00 delimiter; no other header. Every sender address (IP,
port) is a stream of its own, with its own partial frame (at most ``MAX_ENCODED`` bytes),
so a frame split across two datagrams of one sender is joined and never with another
sender's bytes. Each complete frame is checked (SPEC 2.3: COBS, version, type, length, CRC,
anchor id; anchor-to-host types only) and the valid ones go on to the gateway, whole, as
one chunk per datagram under this input's name: the gateway's decoder then never holds a
partial frame of a UDP sender, and a capture of the run replays as any other.

Binding: to HOST (default ``0.0.0.0``, every IPv4 interface, for anchors on the network;
``udp:127.0.0.1:PORT`` accepts this host's senders only, ``udp:[::]:PORT`` IPv6). Receiving
only: the anchors are configured over their serial port (``pfdoa anchors`` lists them on
UDP too).

Bounds and rejections (untrusted datagrams never grow memory; every rejection is counted,
by kind, in ``rejected``, in every health snapshot and the final counters):

* a datagram above :data:`MAX_DATAGRAM` bytes is dropped unread (``oversized``);
* at most :data:`MAX_SENDERS` senders are tracked. A sender silent for :data:`SENDER_IDLE_S`
  (the injected clock's monotonic time) is let go (``senders_idle``: an anchor that
  restarted on a new port leaves its old address behind). When the table is full, a new
  sender takes the place of the least recently heard sender that has never sent a valid
  frame (``senders_evicted``), so one-off senders of noise never keep an anchor out; when
  every tracked sender has sent valid frames, the new one's datagram is dropped
  (``no_room``);
* a frame that fails a check is counted by its error (``bad_crc``, ``bad_cobs``, ...), in
  total and per sender (``per_sender``: datagrams, frames, bad_frames, for the tracked ones).

The kernel's receive buffer is the socket's default; datagrams it dropped while the
gateway was behind are counted where the kernel says (``kernel_drops``, Linux).
"""

from __future__ import annotations

import errno
import select
import socket
import struct
import threading
from collections import Counter, OrderedDict

from pfdoa.clock import Clock
from pfdoa.errors import InputError
from pfdoa.gateway.inputs import InputContext, InputSpec
from pfdoa.gateway.transports import READ_MAX, Chunk, Item, Transport, TransportError, TransportFatal
from pfdoa.protocol import defs
from pfdoa.protocol.uart import ANCHOR_TO_HOST, Decoded, decode_frame, frame_type

MAX_DATAGRAM = READ_MAX  # bytes; a larger datagram is dropped (oversized)
MAX_SENDERS = 64  # sender addresses tracked at once
SENDER_IDLE_S = 30.0  # a sender silent this long is let go
READ_BATCH = 256  # datagrams per read at most (more may be waiting: caught_up_to stays None)
_SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)  # Linux: the kernel's drop count with each datagram


def parse_address(arg: str, where: str) -> tuple[str, int]:
    """``[HOST:]PORT`` -> (host, port); HOST may be ``[IPv6]``; default ``0.0.0.0``."""
    host, sep, port = arg.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    elif ":" in host or "[" in host or "]" in host:
        host = "\0"  # an IPv6 address without its brackets, or a stray bracket
    if not sep:
        host = "0.0.0.0"
    if not port.isdigit() or not 1 <= int(port) <= 65535 or not host or "\0" in host:
        raise InputError(f"{where}: expected udp:[HOST:]PORT, a port in 1..65535 (e.g. udp:5000, "
                         "udp:127.0.0.1:5000, udp:[::1]:5000)")
    return host, int(port)


class _Sender:
    """One sender's stream: its partial frame and what it sent."""

    __slots__ = ("pending", "discarding", "datagrams", "frames", "bad", "last")

    def __init__(self, now: float) -> None:
        self.pending = b""
        self.discarding = False  # inside an overlong frame: dropped up to the next 0x00
        self.datagrams = 0
        self.frames = 0  # valid frames
        self.bad = 0  # frames that failed a check
        self.last = now

    def feed(self, data: bytes, rejected: Counter) -> list[bytes]:
        """The valid complete frames (without their delimiter) this datagram ends."""
        parts = (self.pending + data).split(b"\x00")
        tail = parts.pop()
        if self.discarding and parts:  # the overlong frame (counted) ends at the first delimiter
            parts[0], self.discarding = b"", False
        good = []
        for frame in parts:
            if not frame:
                continue  # back-to-back delimiters
            r = decode_frame(frame)
            if isinstance(r, Decoded) and frame_type(frame) in ANCHOR_TO_HOST:
                good.append(frame)
                continue
            self.bad += 1
            rejected[str(r) if not isinstance(r, Decoded) else "unknown_type"] += 1  # a host-to-anchor frame
        if self.discarding:
            tail = b""
        elif len(tail) > defs.MAX_ENCODED:
            self.bad += 1
            rejected["overlong"] += 1
            self.discarding, tail = True, b""
        self.pending = tail
        self.frames += len(good)
        return good


class UdpTransport(Transport):
    decoder_sources = 1  # whole valid frames, under one source name

    def __init__(self, host: str, port: int, name: str = "udp", clock: Clock | None = None,
                 where: str | None = None) -> None:
        super().__init__(clock)
        self.host, self.port, self.name = host, port, name
        self.where = where or f"--input udp:{host}:{port}"
        self._sock: socket.socket | None = None
        self._senders: OrderedDict[tuple, _Sender] = OrderedDict()  # least recently heard first
        self._lock = threading.Lock()  # counters() is read by the health thread
        self.datagrams = self.bytes = self.frames = 0
        self.admitted = self.evicted = self.idle = 0
        self.kernel_drops = 0
        self.rejected: Counter[str] = Counter()

    @classmethod
    def from_spec(cls, spec: InputSpec, ctx: InputContext, index: int) -> "UdpTransport":
        host, port = parse_address(spec.arg, spec.where())
        return cls(host, port, name=f"udp{index}", clock=ctx.clock, where=spec.where())

    def _open(self) -> None:
        try:
            family, _, _, _, addr = socket.getaddrinfo(self.host, self.port, type=socket.SOCK_DGRAM)[0]
            sock = socket.socket(family, socket.SOCK_DGRAM)
        except OSError as exc:  # an unknown host name, no IPv6 here
            raise TransportFatal(f"{self.where}: {exc}") from None
        try:
            try:
                sock.setsockopt(socket.SOL_SOCKET, _SO_RXQ_OVFL, 1)
            except OSError:
                pass  # not Linux: the kernel's drops are not counted
            sock.bind(addr)
        except OSError as exc:
            sock.close()
            why = {errno.EADDRINUSE: "the port is in use", errno.EACCES: "permission denied (a port below 1024)",
                   errno.EADDRNOTAVAIL: "not an address of this host"}.get(exc.errno or 0, str(exc))
            raise TransportFatal(f"{self.where}: cannot receive there: {why}") from None
        sock.setblocking(False)
        self._sock = sock

    def _read(self, timeout: float) -> list[Item]:
        sock = self._sock
        assert sock is not None  # open
        with self._lock:
            self._let_idle_go(self.clock.monotonic())
        select.select([sock], [], [], timeout)
        out: list[Item] = []
        for _ in range(READ_BATCH):
            t = self.clock.now()  # stamp, then look (see SerialTransport._read)
            try:
                data, anc, _, addr = sock.recvmsg(MAX_DATAGRAM + 1, socket.CMSG_SPACE(4))
            except BlockingIOError:
                self.caught_up_to = t
                break
            except OSError as exc:
                raise TransportError(f"{self.where}: {exc}") from None
            frames = self._datagram(data, addr, anc)
            if frames:
                out.append(Chunk(self.name, self.clock.now(), b"\x00".join(frames) + b"\x00"))
        return out

    def _datagram(self, data: bytes, addr: tuple, anc: list) -> list[bytes]:
        now = self.clock.monotonic()
        with self._lock:
            for level, kind, value in anc:
                if level == socket.SOL_SOCKET and kind == _SO_RXQ_OVFL and len(value) >= 4:
                    self.kernel_drops = struct.unpack("=I", value[:4])[0]
            self.datagrams += 1
            self.bytes += len(data)
            self._let_idle_go(now)
            if len(data) > MAX_DATAGRAM:
                self.rejected["oversized"] += 1
                return []
            key = addr[:2]
            s = self._senders.get(key)
            if s is None:
                s = self._admit(key, now)
                if s is None:
                    self.rejected["no_room"] += 1
                    return []
            else:
                self._senders.move_to_end(key)
            s.last = now
            s.datagrams += 1
            frames = s.feed(data, self.rejected)
            self.frames += len(frames)
            return frames

    def _let_idle_go(self, now: float) -> None:
        while self._senders:
            key, s = next(iter(self._senders.items()))
            if now - s.last < SENDER_IDLE_S:
                return
            del self._senders[key]
            self.idle += 1

    def _admit(self, key: tuple, now: float) -> _Sender | None:
        if len(self._senders) >= MAX_SENDERS:
            noise = next((k for k, s in self._senders.items() if not s.frames), None)
            if noise is None:
                return None
            del self._senders[noise]
            self.evicted += 1
        self.admitted += 1
        s = self._senders[key] = _Sender(now)
        return s

    def counters(self) -> dict:
        """Datagrams, bytes, valid frames, senders (tracked, admitted, evicted, let go idle),
        rejections by kind, the kernel's drops, and per tracked sender its datagrams, frames
        and bad frames."""
        with self._lock:
            return {"datagrams": self.datagrams, "bytes": self.bytes, "frames": self.frames,
                    "senders": len(self._senders), "senders_admitted": self.admitted,
                    "senders_evicted": self.evicted, "senders_idle": self.idle, "kernel_drops": self.kernel_drops,
                    "rejected": dict(sorted(self.rejected.items())),
                    "per_sender": {_label(k): {"datagrams": s.datagrams, "frames": s.frames, "bad_frames": s.bad}
                                   for k, s in self._senders.items()}}

    def _close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()


def _label(addr: tuple) -> str:
    host, port = addr[0], addr[1]
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
