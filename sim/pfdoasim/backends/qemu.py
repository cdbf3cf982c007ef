"""``qemu``: the real Cortex-M3 firmware image (firmware/ports/qemu_mps2) in the loop.

Each :class:`QemuAnchor` is one ``qemu-system-arm -M mps2-an385`` process running the SIL
image (``pfdoa_anchor_sil.elf``, built with ``PFDOA_SIL_INJECT``). Its UART0 is a
pseudo-terminal: the gateway opens it like a USB serial port and reads the anchor's
frames; the simulator writes ``RADIO_INJECT`` frames into it, which the firmware feeds to
its radio receive path. Anchor id, boot tick and the configuration found in "flash" at
first boot are passed on the semihosting command line (``arg=id=N`` ...).

Start-up is race-free: QEMU starts paused (``-S``), the pty is opened, then the guest is
resumed through QMP on QEMU's stdin/stdout. The guest's first frame (its first STATUS) is
the banner; nothing is sent before it arrived. ``-icount shift=0`` makes the guest's
instruction timing deterministic; the SIL image's clock is the injected ticks anyway.

:class:`QemuPool` is the backend's anchor factory; :mod:`pfdoasim.qemu_harness` runs
``pfdoa sim --anchor-backend qemu`` with it. Everything here needs a checkout's firmware
tree (the port's sources and Makefile, :mod:`pfdoasim.firmware`); a pip installation
says so in one line.
"""

from __future__ import annotations

import errno
import json
import logging
import os
import re
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import tty
from pathlib import Path
from typing import Any, BinaryIO, Sequence

from pfdoa.errors import InputError
from pfdoa.protocol import RadioInject, RadioInjectRaw, decode_frame, defs, encode_uart, frame_type
from pfdoa.protocol.anchor_model import AnchorConfig
from pfdoa.protocol.beacons import adv_pdu
from pfdoa.protocol.defs import DecodeError
from pfdoa.protocol.filters import BeaconFilter, pack_table
from pfdoa.protocol.messages import RadioTx
from pfdoasim import firmware
from pfdoasim.backends.base import AnchorCore, AnchorFactory, Backend, RawReceiver

log = logging.getLogger(__name__)

# The port's images (firmware/ports/qemu_mps2/Makefile writes them to build/qemu_mps2).
SIL = "pfdoa_anchor_sil.elf"
PROD = "pfdoa_anchor.elf"
SELFTEST = "port_selftest.elf"

QEMU = "qemu-system-arm"
MACHINE = "mps2-an385"
_PTY_RE = re.compile(rb"char device redirected to (/dev/pts/\d+)")


def port_dir() -> Path:
    """The QEMU port's folder in the located firmware tree (InputError when it has none)."""
    return firmware.locate().part("qemu port")


def build_dir() -> Path:
    return firmware.locate().build_dir / "qemu_mps2"


def image_path(name: str = SIL) -> Path:
    """One of the port's images (:data:`SIL`, :data:`PROD`, :data:`SELFTEST`), built or not."""
    port_dir()
    return build_dir() / name


def build_images(quiet: bool = True) -> Path:
    """Build the port's images (make is incremental); returns the build directory."""
    port = port_dir()
    if shutil.which("arm-none-eabi-gcc") is None:
        raise InputError("arm-none-eabi-gcc not found: run tools/bootstrap.sh qemu "
                         "(apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi)")
    with firmware.build_lock(build_dir()):
        r = subprocess.run(["make", "-C", str(port), "all"], capture_output=True, text=True)
    if r.returncode != 0:
        raise InputError(f"building the QEMU firmware image failed:\n{r.stdout[-2000:]}{r.stderr[-2000:]}")
    if not quiet:
        sys.stderr.write(r.stdout)
    return build_dir()


def qemu_command(image: Path, params: dict[str, str], qemu: str = QEMU, machine: str = MACHINE,
                 serial: str = "pty") -> list[str]:
    """The QEMU command line for one paused anchor, QMP on stdio; UART0 on a pty QEMU makes
    (``serial`` "pty") or on the tty device ``serial`` names."""
    if shutil.which(qemu) is None:
        raise InputError(f"{qemu} not found: run tools/bootstrap.sh qemu (apt-get install qemu-system-arm)")
    # Semihosting arguments are split on commas by QEMU's option parser: values stay plain.
    semi = "enable=on,target=native,arg=pfdoa_anchor" + "".join(f",arg={k}={v}" for k, v in params.items())
    return [qemu, "-M", machine, "-display", "none", "-monitor", "none", "-serial", serial,
            "-qmp", "stdio", "-S", "-icount", "shift=0", "-semihosting-config", semi,
            "-kernel", str(image)]


def config_hex(settings) -> str:
    """The 7 stored configuration bytes (the CONFIG_SET payload without its token) as the
    firmware's cfg= parameter expects them; settings has AnchorConfig's fields."""
    return AnchorConfig(settings.offset_q8, settings.alpha_q8, settings.spike_db, settings.report_mode,
                        settings.decimation).pack().hex()


class QemuAnchor:
    """One firmware image running in QEMU, its UART0 on a pseudo-terminal.

    ``start()`` boots it and returns the banner (the first whole frame, with its 0x00);
    ``serial_path`` is the pty for the gateway; ``write``/``inject`` send to the anchor's
    UART RX; ``read`` returns what it sent (only while nobody else reads the pty);
    ``reset()`` is a warm reset (the RAM configuration store survives); ``stop()`` ends
    QEMU and returns its exit status (the firmware's, if it exited via semihosting).
    """

    def __init__(self, image: str | Path | None = None, anchor_id: int = 1, *, boot_tick: int | None = None,
                 config: str | None = None, filters: str | None = None, qemu: str = QEMU, machine: str = MACHINE,
                 own_pty: bool = True) -> None:
        self.image = Path(image) if image is not None else image_path(SIL)
        # own_pty: we make the pty and keep its master; QEMU opens the slave. What the guest
        # sent before it exited stays readable (a slave read after QEMU closed its own pty's
        # master loses it). False: QEMU's own pty, whose path another process (a gateway
        # in real time) opens.
        self.own_pty = own_pty
        self.anchor_id = anchor_id
        self.params = {"id": str(anchor_id)}
        if boot_tick is not None:
            self.params["tick"] = str(boot_tick & 0xFFFFFFFF)
        if config is not None:
            self.params["cfg"] = config
        if filters is not None:  # the packed filter table as hex (board.h: filters=)
            self.params["filters"] = filters
        self.qemu, self.machine = qemu, machine
        self.proc: subprocess.Popen | None = None
        self.serial_path: str | None = None
        self.fd: int | None = None
        self._stderr: BinaryIO | None = None
        self._qmp_buf = b""

    # The process and the pty exist between start() and stop(); used outside, a clear error.
    def _proc(self) -> subprocess.Popen:
        if self.proc is None:
            raise InputError(f"QEMU anchor {self.anchor_id}: not started")
        return self.proc

    def port(self) -> str:
        """The anchor's serial port (the pty's path), once started."""
        if self.serial_path is None:
            raise InputError(f"QEMU anchor {self.anchor_id}: not started")
        return self.serial_path

    def _fd(self) -> int:
        if self.fd is None:
            raise InputError(f"QEMU anchor {self.anchor_id}: its serial port is not open")
        return self.fd

    def _pipe(self, name: str) -> int:
        f = getattr(self._proc(), name)
        if f is None:
            raise InputError(f"QEMU anchor {self.anchor_id}: no {name} pipe")
        return int(f.fileno())

    # -- life cycle ---------------------------------------------------------------------
    def start(self, timeout_s: float = 10.0) -> bytes:
        if not self.image.exists():
            raise InputError(f"{self.image}: no such firmware image (make -C {port_dir()})")
        slave = -1
        if self.own_pty:
            self.fd, slave = os.openpty()
            tty.setraw(self.fd)  # raw before any byte (toolchain notes section 5)
            tty.setraw(slave)
            os.set_blocking(self.fd, False)
            self.serial_path = os.ttyname(slave)
            cmd = qemu_command(self.image, self.params, self.qemu, self.machine, serial=self.serial_path)
        else:
            cmd = qemu_command(self.image, self.params, self.qemu, self.machine)
        log.debug("qemu: %s", " ".join(cmd))
        self._stderr = stderr = tempfile.TemporaryFile()
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=stderr,
                                     preexec_fn=_die_with_parent)
        end = time.monotonic() + timeout_s
        try:
            if not self.own_pty:
                self.serial_path = self._wait_pty(end)
                # Open (and keep open) the slave before the guest runs: QEMU drops UART output
                # while no one has the pty open, and the banner must not be lost.
                self.fd = os.open(self.serial_path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
                tty.setraw(self.fd)
            self._qmp("qmp_capabilities", end)
            if slave >= 0:
                os.close(slave)  # QEMU has its own: the slave is open while QEMU runs
                slave = -1
            self._qmp("cont", end)
            return self._read_until_delimiter(end)
        except BaseException:
            if slave >= 0:
                os.close(slave)
            self.stop()
            raise

    def _wait_pty(self, end: float) -> str:
        """QEMU announces the pty with qemu_printf: on stdout (before the QMP greeting) when
        the monitor is not on stdio, on stderr in other set-ups; look at both."""
        out = self._pipe("stdout")
        while True:
            m = _PTY_RE.search(self._qmp_buf)
            if m:
                self._qmp_buf = self._qmp_buf[m.end():]
                return m.group(1).decode()
            m = _PTY_RE.search(self.stderr_text().encode())
            if m:
                return m.group(1).decode()
            left = end - time.monotonic()
            if self._proc().poll() is not None or left <= 0:
                raise InputError(f"QEMU did not start ({self.stderr_text().strip() or 'no output'})")
            if select.select([out], [], [], min(left, 0.05))[0]:
                self._qmp_buf += os.read(out, 4096)

    def _qmp(self, command: str, end: float) -> dict:
        """One QMP command; skips the greeting and asynchronous events."""
        out = self._pipe("stdout")
        os.write(self._pipe("stdin"), json.dumps({"execute": command}).encode() + b"\n")
        while True:
            while b"\n" not in self._qmp_buf:
                left = end - time.monotonic()
                if left <= 0 or not select.select([out], [], [], left)[0]:
                    raise InputError(f"QEMU: no QMP reply to {command}")
                chunk = os.read(out, 4096)
                if not chunk:
                    raise InputError(f"QEMU exited during {command}: {self.stderr_text().strip()}")
                self._qmp_buf += chunk
            line, self._qmp_buf = self._qmp_buf.split(b"\n", 1)
            if not line.lstrip().startswith(b"{"):
                continue  # the rest of QEMU's "char device redirected" line
            msg = json.loads(line)
            if "return" in msg:
                return msg
            if "error" in msg:
                raise InputError(f"QEMU: {command}: {msg['error'].get('desc')}")

    def _read_until_delimiter(self, end: float) -> bytes:
        buf = bytearray()
        while not buf.endswith(b"\x00"):
            left = end - time.monotonic()
            if left <= 0:
                raise InputError(f"QEMU anchor {self.anchor_id}: no banner frame within the timeout")
            buf += self.read(left, max_bytes=1)
        return bytes(buf)

    def reset(self, timeout_s: float = 5.0) -> None:
        """Warm reset of the guest (QMP system_reset): the firmware boots again."""
        self._qmp("system_reset", time.monotonic() + timeout_s)

    def stop(self, timeout_s: float = 2.0) -> int | None:
        """Quit QEMU; returns its exit status (None if it had to be killed)."""
        rc = None
        proc = self.proc
        if proc is not None:
            if proc.poll() is None and proc.stdin is not None:
                try:
                    proc.stdin.write(b'{"execute": "quit"}\n')
                    proc.stdin.flush()
                except (BrokenPipeError, OSError):
                    pass
            try:
                rc = proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            for f in (proc.stdin, proc.stdout):
                if f is not None:
                    f.close()
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None
        return rc

    def wait(self, timeout_s: float) -> int:
        """Wait for the guest to end QEMU (semihosting exit); returns the status."""
        return self._proc().wait(timeout=timeout_s)

    def stderr_text(self) -> str:
        if self._stderr is None:
            return ""
        self._stderr.seek(0)
        return self._stderr.read().decode(errors="replace")

    def __enter__(self) -> "QemuAnchor":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- UART ---------------------------------------------------------------------------
    def write(self, data: bytes, timeout_s: float = 5.0) -> None:
        """All of data to the anchor's UART RX (the guest back-pressures when busy)."""
        view = memoryview(data)
        end = time.monotonic() + timeout_s
        while view:
            try:
                n = os.write(self._fd(), view)
                view = view[n:]
            except OSError as exc:
                if exc.errno != errno.EAGAIN:
                    raise InputError(f"QEMU anchor {self.anchor_id}: its UART is gone ({exc.strerror}; "
                                     f"QEMU status {self._proc().poll()})") from None
                left = end - time.monotonic()
                if left <= 0:
                    raise InputError(f"QEMU anchor {self.anchor_id}: UART RX stalled") from None
                select.select([], [self._fd()], [], min(left, 0.05))

    def inject(self, seq: int, rssi_dbm: int, channel: int, lqi: int, radio: int, tick_ms: int) -> None:
        """One radio reading, as a RADIO_INJECT frame addressed to this anchor."""
        self.write(inject_frame(self.anchor_id, seq, rssi_dbm, channel, lqi, radio, tick_ms))

    def exchange(self, data: bytes, expect_bytes: int, timeout_s: float = 30.0, settle_s: float = 0.2) -> bytes:
        """Send data while collecting the anchor's output (so neither direction's pty buffer
        stalls the other) until expect_bytes arrived and nothing more came for settle_s."""
        out = bytearray()
        view = memoryview(data)
        end = time.monotonic() + timeout_s
        quiet_until = None
        while True:
            now = time.monotonic()
            if now > end:
                break
            if not view and len(out) >= expect_bytes:
                quiet_until = quiet_until or now + settle_s
                if now >= quiet_until:
                    break
            fd = self._fd()
            wr = [fd] if view else []
            r, w, _ = select.select([fd], wr, [], 0.05)
            if r:
                chunk = self.read(0.0)
                if chunk:
                    out += chunk
                    quiet_until = None
            if w:
                try:
                    view = view[os.write(fd, view[:4096]):]
                except BlockingIOError:
                    pass
        return bytes(out)

    def read_exactly(self, n: int, hang_s: float) -> bytes:
        """Exactly n bytes the anchor sent (waiting for them; InputError after hang_s)."""
        buf = bytearray()
        end = time.monotonic() + hang_s
        while len(buf) < n:
            left = end - time.monotonic()
            if left <= 0:
                raise InputError(f"QEMU anchor {self.anchor_id}: {n - len(buf)} of the {n} bytes the host build "
                                 f"sent did not come within {hang_s:g} s (QEMU status {self._proc().poll()})")
            buf += self.read(min(left, 0.5), max_bytes=n - len(buf))
        return bytes(buf)

    def read(self, timeout_s: float, max_bytes: int = 65536) -> bytes:
        """Bytes the anchor sent: waits up to timeout_s for the first, then takes what is there."""
        fd = self._fd()
        if select.select([fd], [], [], max(timeout_s, 0.0))[0]:
            try:
                return os.read(fd, max_bytes)
            except BlockingIOError:
                return b""
            except OSError as exc:  # EIO: QEMU closed the master
                if exc.errno == errno.EIO:
                    return b""
                raise
        return b""


def _die_with_parent() -> None:
    """In the child before exec: SIGTERM when the process that started QEMU dies, so a
    killed test run leaves no guest behind (Linux prctl PR_SET_PDEATHSIG)."""
    try:
        import ctypes

        ctypes.CDLL(None).prctl(1, signal.SIGTERM)
    except (OSError, AttributeError):
        pass


def inject_frame(anchor_id: int, seq: int, rssi_dbm: int, channel: int, lqi: int, radio: int,
                 tick_ms: int) -> bytes:
    """The wire bytes of one RADIO_INJECT frame (protocol/SPEC.md 1.7)."""
    rssi = max(-128, min(127, int(rssi_dbm)))
    msg = RadioInject(seq=seq & 0xFFFF, tick_ms=tick_ms & 0xFFFFFFFF, rssi_dbm=rssi, channel=channel,
                      lqi=lqi, radio=radio)
    return encode_uart(msg, anchor_id)


def inject_raw_frame(anchor_id: int, frame: bytes, rssi_dbm: int, channel: int, lqi: int, radio: int,
                     tick_ms: int) -> bytes:
    """The wire bytes of one RADIO_INJECT_RAW frame (protocol/SPEC.md 1.7): a BLE advertising
    PDU (radio 0) or an IEEE 802.15.4 MAC frame without FCS (radio 1), at most 39 bytes."""
    if len(frame) > defs.MSG_RADIO_INJECT_RAW_FRAME_LEN:
        raise InputError(f"RADIO_INJECT_RAW: a {len(frame)}-byte frame (at most "
                         f"{defs.MSG_RADIO_INJECT_RAW_FRAME_LEN})")
    rssi = max(-128, min(127, int(rssi_dbm)))
    msg = RadioInjectRaw.of(tick_ms & 0xFFFFFFFF, rssi, channel, lqi, radio, bytes(frame))
    return encode_uart(msg, anchor_id)


# -- the simulator's side ---------------------------------------------------------------
class QemuCore(AnchorCore):
    """A QEMU anchor behind the simulator's AnchorCore interface (pfdoasim.backends.base).

    Readings become RADIO_INJECT frames; raw receptions (:class:`RawReceiver`: another
    beacon's advertisement, an 802.15.4 frame) RADIO_INJECT_RAW frames, which the firmware
    matches against its filter table. ``poll`` is a no-op: the SIL firmware polls itself
    at the tick of each injection (there is no message that advances its clock alone), so
    a BLE event with fewer than 3 readings closes at the next injection instead of by the
    20 ms timeout, and an event formed by time closes at the first injection after its
    period.

    With a ``shadow`` (virtual time) the same reading goes into a host build of the core,
    and ``take_uart`` returns exactly as many bytes from QEMU as the shadow sent (waiting
    for them: the barrier), counting the bytes that differ. Without one (real time) the
    frames go straight from the pty to the gateway and ``take_uart`` is always empty.

    The SIL image's radio sends the anchor's own advertisement as a RADIO_TX frame on the
    UART (protocol/SPEC.md 1.7); ``take_uart`` keeps those (compared with the shadow's, which
    sends them the same way) for ``take_radio`` and hands out the rest.
    """

    def __init__(self, anchor: QemuAnchor, shadow: _Shadow | _LazyShadow | None = None, banner: bytes = b"",
                 hang_s: float = 30.0) -> None:
        self.q = anchor
        self.anchor_id = anchor.anchor_id
        self.shadow = shadow
        self.hang_s = hang_s
        self.injected = 0
        self.mismatched = 0  # bytes that differ from the host build's
        self.bytes = 0
        self._pending = b""  # QEMU bytes read but not yet handed out (the banner)
        self._radio: list[tuple[int, bytes]] = []  # the RADIO_TX frames' advertisements
        if shadow is not None and banner:
            self._pending = banner

    def radio(self, seq: int, rssi_dbm: int, channel: int, lqi: int, radio: int, tick_ms: int) -> None:
        self.q.inject(seq, rssi_dbm, channel, lqi, radio, tick_ms)
        self.injected += 1
        if self.shadow is not None:
            self.shadow.radio(seq, rssi_dbm, channel, lqi, radio, tick_ms)
            self.shadow.poll(tick_ms)  # as the SIL image does after each injected reading

    def _raw(self, frame: bytes, rssi_dbm: int, channel: int, lqi: int, radio: int, tick_ms: int) -> int:
        """One RADIO_INJECT_RAW; the shadow gets the same frame through the same entry point
        and is polled at its tick as the image polls itself. Returns the shadow's result
        (1 matched, 0 no entry matched, negative dropped), 1 without a shadow (not known)."""
        self.q.write(inject_raw_frame(self.anchor_id, frame, rssi_dbm, channel, lqi, radio, tick_ms))
        self.injected += 1
        if self.shadow is None:
            return 1
        rc = self.shadow.raw(frame, rssi_dbm, channel, lqi, radio, tick_ms)
        self.shadow.poll(tick_ms)
        return rc

    def ble_adv(self, adv_a: bytes, adv_data: bytes, rssi_dbm: int, channel: int, tick_ms: int) -> int:
        return self.ble_pdu(adv_pdu(adv_a, adv_data), rssi_dbm, channel, tick_ms)

    def ble_pdu(self, pdu: bytes, rssi_dbm: int, channel: int, tick_ms: int) -> int:
        return self._raw(pdu, rssi_dbm, channel, 0, defs.RADIO_BLE, tick_ms)

    def ieee802154(self, mpdu: bytes, rssi_dbm: int, channel: int, lqi: int, tick_ms: int) -> int:
        return self._raw(mpdu, rssi_dbm, channel, lqi, defs.RADIO_IEEE802154, tick_ms)

    def poll(self, tick_ms: int) -> None:
        pass

    def uart_rx(self, data: bytes, tick_ms: int) -> None:
        self.q.write(data)

    def can_rx(self, can_id: int, data: bytes) -> None:
        pass

    def take_uart(self) -> bytes:
        if self.shadow is None:
            return b""
        expected = self.shadow.take_uart()
        got = self._pending[: len(expected)]
        self._pending = self._pending[len(got):]
        if len(got) < len(expected):
            got += self.q.read_exactly(len(expected) - len(got), self.hang_s)
        self.bytes += len(got)
        if got != expected:
            self.mismatched += sum(a != b for a, b in zip(got, expected)) + abs(len(got) - len(expected))
            log.error("QEMU anchor %d: %d bytes differ from the host build's", self.anchor_id, self.mismatched)
        if defs.MSG_RADIO_TX not in got:
            return got  # no RADIO_TX frame: its type byte is in its first COBS group, as sent
        keep = bytearray()
        for piece in got.split(b"\x00")[:-1]:
            if piece and frame_type(piece) == defs.MSG_RADIO_TX:
                d = decode_frame(piece)
                if not isinstance(d, DecodeError) and isinstance(d.message, RadioTx):
                    self._radio.append((d.message.radio, d.message.sent))
                    continue
            keep += piece + b"\x00"
        return bytes(keep) + got[got.rfind(b"\x00") + 1:]

    def take_can(self) -> list[tuple[int, bytes]]:
        return []

    def take_radio(self) -> list[tuple[int, bytes]]:
        out, self._radio = self._radio, []
        return out


class QemuPool:
    """N QEMU anchors started up front; also the simulator's anchor factory. A second boot
    of an anchor (the reboot fault) is a warm reset of its QEMU; the firmware then boots at
    the tick of the first reading injected after it (firmware/ports/qemu_mps2/main.c).

    ``shadows`` (virtual time): a host-core factory (:class:`pfdoasim.backends.c.CoreFactory`)
    for each anchor's shadow core, booted as the firmware boots: at its boot tick with the
    first poll (whose STATUS is the banner) on a cold start, at the first reading after a
    warm reset.

    ``filter_table``: the beacon filter table every anchor's "flash" holds at first boot
    (the firmware's filters= parameter; the shadows' stored table). ``filter_flash`` is
    where the simulator looks for it (pfdoasim.runner), filled before QEMU starts."""

    def __init__(self, anchor_ids, settings=None, image: Path | None = None,
                 shadows: AnchorFactory | None = None, filter_table: Sequence[BeaconFilter] | None = None) -> None:
        self.ids = list(anchor_ids)
        self.settings = settings
        self.image = image if image is not None else image_path(SIL)
        self.shadows = shadows
        self.anchors: dict[int, QemuAnchor] = {}
        self.cores: dict[int, QemuCore] = {}
        self.banners: dict[int, bytes] = {}
        self.boot_ticks: dict[int, int] = {}
        packed = pack_table(filter_table) if filter_table is not None else None
        self.filter_flash: dict[int, bytes] = {a: packed for a in self.ids} if packed is not None else {}
        # The SIL image's radio is BLE (main.c); the simulator sets this for anchors that
        # hear each other, and the shadows then send their advertisements as the image does.
        self.peer_radio: int | None = None

    def start(self, boot_ticks: dict[int, int], timeout_s: float = 20.0) -> None:
        cfg = config_hex(self.settings) if self.settings is not None else None
        self.boot_ticks = dict(boot_ticks)
        try:
            for a in self.ids:
                # Virtual time: we read the anchors; real time: the gateway opens their ptys.
                table = self.filter_flash.get(a)
                q = QemuAnchor(self.image, a, boot_tick=boot_ticks.get(a, 0), config=cfg,
                               filters=table.hex() if table is not None else None, own_pty=self.shadows is not None)
                self.anchors[a] = q
                self.banners[a] = q.start(timeout_s)
                log.info("QEMU anchor %d on %s", a, q.serial_path)
        except BaseException:
            self.stop()
            raise

    def paths(self) -> list[str]:
        return [self.anchors[a].port() for a in self.ids]

    def __call__(self, anchor_id: int, can: bool, settings, boot_tick: int) -> QemuCore:
        if can:
            raise InputError("QEMU anchors speak UART only (use --transport pty)")
        q = self.anchors[anchor_id]
        warm = anchor_id in self.cores
        if warm:
            q.reset()
        shadow: _Shadow | _LazyShadow | None = None
        if self.peer_radio not in (None, defs.RADIO_BLE):
            raise InputError("the QEMU SIL image sends its advertisement over BLE only")
        if self.shadows is not None and self.peer_radio is not None:
            self.shadows.peer_radio = self.peer_radio  # type: ignore[attr-defined]  # the c backend's factory
            self.shadows.radio_tx_on_uart = True  # type: ignore[attr-defined]
        if self.shadows is not None:
            if anchor_id in self.filter_flash:  # the shadow's flash holds what the image's does
                shadow_flash = getattr(self.shadows, "filter_flash", None)
                if shadow_flash is None:
                    raise InputError("the QEMU anchors' shadow cores must keep a filter table (the c backend)")
                shadow_flash.setdefault(anchor_id, self.filter_flash[anchor_id])
            if warm:
                shadow = _LazyShadow(self.shadows, anchor_id, settings)
            else:
                tick = self.boot_ticks.get(anchor_id, boot_tick)
                cold = self.shadows(anchor_id, False, settings, tick)
                cold.poll(tick)  # the image's first poll: its banner STATUS
                shadow = _Shadow(cold)
        core = self.cores[anchor_id] = QemuCore(q, shadow, b"" if warm else self.banners.get(anchor_id, b""))
        return core

    def stop(self) -> dict[int, int | None]:
        return {a: q.stop() for a, q in self.anchors.items()}

    def summary(self) -> dict:
        return {"image": str(self.image), "injected": {str(a): c.injected for a, c in self.cores.items()},
                "bytes_compared": {str(a): c.bytes for a, c in self.cores.items()} if self.shadows else None,
                "byte_mismatches": sum(c.mismatched for c in self.cores.values()) if self.shadows else None}


def _shadow_raw(core: AnchorCore, frame: bytes, rssi_dbm: int, channel: int, lqi: int, radio: int,
                tick_ms: int) -> int:
    """A RADIO_INJECT_RAW's frame into a host core, through the entry point the image's
    core calls for it (anchor.c: pfdoa_anchor_on_ble_pdu / pfdoa_anchor_on_802154)."""
    if not isinstance(core, RawReceiver):
        raise InputError("the QEMU anchors' shadow cores must match raw frames (the c backend)")
    if radio == defs.RADIO_BLE:
        return core.ble_pdu(frame, rssi_dbm, channel, tick_ms)
    return core.ieee802154(frame, rssi_dbm, channel, lqi, tick_ms)


class _Shadow:
    """The shadow of a cold-started anchor: a host core, booted with the image."""

    def __init__(self, core: AnchorCore) -> None:
        self.core = core

    def radio(self, seq: int, rssi_dbm: int, channel: int, lqi: int, radio: int, tick_ms: int) -> None:
        self.core.radio(seq, rssi_dbm, channel, lqi, radio, tick_ms)

    def raw(self, frame: bytes, rssi_dbm: int, channel: int, lqi: int, radio: int, tick_ms: int) -> int:
        return _shadow_raw(self.core, frame, rssi_dbm, channel, lqi, radio, tick_ms)

    def poll(self, tick_ms: int) -> None:
        self.core.poll(tick_ms)

    def take_uart(self) -> bytes:
        return self.core.take_uart()


class _LazyShadow:
    """The shadow of a warm-reset anchor: it boots at the first injection's tick, as the image."""

    def __init__(self, factory: AnchorFactory, anchor_id: int, settings: Any) -> None:
        self.factory, self.anchor_id, self.settings = factory, anchor_id, settings
        self.core: AnchorCore | None = None

    def _boot(self, tick_ms: int) -> AnchorCore:
        if self.core is None:
            self.core = self.factory(self.anchor_id, False, self.settings, tick_ms)
        return self.core

    def radio(self, seq: int, rssi_dbm: int, channel: int, lqi: int, radio: int, tick_ms: int) -> None:
        self._boot(tick_ms).radio(seq, rssi_dbm, channel, lqi, radio, tick_ms)

    def raw(self, frame: bytes, rssi_dbm: int, channel: int, lqi: int, radio: int, tick_ms: int) -> int:
        return _shadow_raw(self._boot(tick_ms), frame, rssi_dbm, channel, lqi, radio, tick_ms)

    def poll(self, tick_ms: int) -> None:
        if self.core is not None:
            self.core.poll(tick_ms)

    def take_uart(self) -> bytes:
        return self.core.take_uart() if self.core is not None else b""


class QemuBackend(Backend):
    """Each anchor is a QEMU process with its own serial port: runs go through
    :mod:`pfdoasim.qemu_harness`, which builds a :class:`QemuPool` for the run's anchors."""

    name = "qemu"
    in_process = False

    def factory(self, core_lib: str | None = None) -> AnchorFactory:
        raise InputError("the qemu backend's anchors are processes with their own serial ports: "
                         "run it through pfdoa sim --anchor-backend qemu (pfdoasim.qemu_harness)")

