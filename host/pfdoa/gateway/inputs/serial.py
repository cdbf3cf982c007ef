"""``serial:URL[@BAUD]``: anything pyserial's ``serial_for_url`` opens.

``/dev/ttyUSB0``, ``/dev/pts/3``, ``loop://``, ``socket://host:port``,
``rfc2217://host:port``; a baud rate may follow the URL after ``@`` (``/dev/ttyACM0@921600``;
default ``[gateway] serial_baud``). Device files are opened exclusively (a second reader on
the same tty would steal bytes). Bidirectional: ``pfdoa anchors`` sends on it.
"""

from __future__ import annotations

import errno
import os
import re
import termios
from typing import Any

from pfdoa.clock import Clock
from pfdoa.errors import InputError
from pfdoa.gateway.inputs import InputContext, InputSpec
from pfdoa.gateway.transports import (
    READ_MAX,
    Chunk,
    Item,
    Transport,
    TransportAbsent,
    TransportError,
    TransportFatal,
    is_char_device,
    open_error,
)


def split_baud(spec: str, default: int) -> tuple[str, int]:
    """``URL[@BAUD]`` -> (url, baud). Only a trailing all-digit ``@`` part is a baud rate."""
    m = re.fullmatch(r"(.+)@(\d+)", spec)
    if m:
        return m.group(1), int(m.group(2))
    return spec, default


class SerialTransport(Transport):
    bidirectional = True
    decoder_sources = 1

    def __init__(self, url: str, baudrate: int = 115200, name: str | None = None,
                 clock: Clock | None = None, where: str | None = None) -> None:
        super().__init__(clock)
        self.url = url
        self.baudrate = baudrate
        self.name = name or url
        self.where = where or f"--serial {url}"
        self._port: Any = None  # a pyserial port while open
        self._failed: Exception | None = None

    @classmethod
    def from_spec(cls, spec: InputSpec, ctx: InputContext, index: int) -> "SerialTransport":
        if not spec.arg:
            raise InputError(f"{spec.where()}: expected serial:URL[@BAUD] (e.g. serial:/dev/ttyACM0@115200, "
                             "serial:rfc2217://host:4000)")
        url, baud = split_baud(spec.arg, ctx.serial_baud)
        return cls(url, baud, name=f"serial{index}", clock=ctx.clock,
                   where=None if spec.option == "--serial" else spec.where())

    def _open(self) -> None:
        import serial

        self._failed = None
        local = "://" not in self.url
        if local and os.path.exists(self.url) and not is_char_device(self.url):
            raise TransportFatal(f"{self.where}: not a serial device (a regular file or directory)")
        if local and not os.path.exists(self.url):
            raise TransportAbsent("--serial", self.url, self.where)
        try:
            # exclusive: a second reader on the same tty would steal bytes.
            kw: dict[str, Any] = {"exclusive": True} if local else {}
            self._port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0.1, **kw)
        except ValueError as exc:  # a malformed URL or parameter: retrying cannot help
            raise TransportFatal(f"{self.where}: {exc}") from None
        except (serial.SerialException, OSError) as exc:
            raise open_error("--serial", self.url, exc, local, self.where) from None

    def _read(self, timeout: float) -> list[Item]:
        import serial

        port = self._port
        if self._failed is not None:  # the device failed after the bytes it still delivered
            exc, self._failed = self._failed, None
            raise TransportError(f"{self.url}: {exc}")
        data = b""
        try:
            if port.timeout != timeout:
                port.timeout = timeout
            data = port.read(1)
            if data:
                waiting = port.in_waiting
                if waiting:
                    data += port.read(min(waiting, READ_MAX - 1))
            # Stamp, then look: if nothing is waiting now, nothing arrived before the stamp
            # that we have not read (a stamp taken after the look could hide a byte).
            t = self.clock.now()
            if not port.in_waiting:
                self.caught_up_to = t
        except (serial.SerialException, OSError) as exc:
            if not data:
                raise TransportError(f"{self.url}: {exc}") from None
            self._failed = exc  # deliver what was read; the error comes with the next read
            t = self.clock.now()
        return [Chunk(self.name, t, bytes(data))] if data else []

    def _send(self, data: bytes, can_id: int | None) -> None:
        import serial

        if can_id is not None:
            raise TransportFatal(f"{self.name}: a serial port carries UART frames, not CAN frames")
        try:
            self._port.write(data)
            self._drain()
        except (serial.SerialException, OSError, termios.error) as exc:
            raise TransportError(f"{self.url}: {exc}") from None

    def _drain(self) -> None:
        """Wait until the frame has left (pyserial's flush: tcdrain). A signal there (its
        handler has run: pfdoa.signals) makes tcdrain fail with EINTR, which the termios
        module does not retry: drain on."""
        while True:
            try:
                self._port.flush()
                return
            except termios.error as exc:
                if not (exc.args and exc.args[0] == errno.EINTR):
                    raise

    def _close(self) -> None:
        port, self._port = self._port, None
        if port is not None:
            port.close()
