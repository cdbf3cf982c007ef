"""``stdin``: the UART byte stream on standard input (or any readable file descriptor).

A finite input: it ends when standard input does (never dropped: its reader waits when
the pipeline is behind). A terminal is refused (its line discipline would edit and echo
the binary frames); ``capture:-`` reads a *timed* stream from standard input instead.
"""

from __future__ import annotations

import os
import select
import sys

from pfdoa.clock import Clock
from pfdoa.errors import InputError
from pfdoa.gateway.inputs import InputContext, InputSpec
from pfdoa.gateway.transports import READ_MAX, Chunk, Item, Transport, TransportEOF, TransportError, TransportFatal


class StdinTransport(Transport):
    """The raw byte stream on standard input (or any readable file descriptor)."""

    finite = True
    decoder_sources = 1
    reads_stdin = True

    def __init__(self, fd: int | None = None, name: str = "stdin", clock: Clock | None = None,
                 where: str = "--stdin") -> None:
        super().__init__(clock)
        self._fd = fd  # None: standard input's, looked up when it opens
        self.fd = -1
        self.name = name
        self.where = where

    @classmethod
    def from_spec(cls, spec: InputSpec, ctx: InputContext, index: int) -> "StdinTransport":
        if spec.arg:
            raise InputError(f"{spec.where()}: stdin takes no argument (standard input is one stream)")
        return cls(clock=ctx.clock, where=spec.where())

    def _open(self) -> None:
        self.fd = (sys.stdin.fileno() if sys.stdin is not None else -1) if self._fd is None else self._fd
        if self.fd < 0:  # started with standard input closed (`<&-`)
            raise TransportFatal(f"{self.where}: standard input is closed; pipe the anchors' byte stream in")
        if os.isatty(self.fd):
            # A terminal in cooked mode would edit and echo the bytes: anchors' frames are binary.
            raise TransportFatal(f"{self.where} is a terminal; pipe the anchors' byte stream in "
                                 f"(e.g. some-anchor-sim | pfdoa gateway ... {self.where})")

    def _read(self, timeout: float) -> list[Item]:
        r, _, _ = select.select([self.fd], [], [], timeout)
        data = b""
        if r:
            try:
                data = os.read(self.fd, READ_MAX)
            except OSError as exc:
                if exc.errno == 5:  # EIO: the other side of a pty closed
                    raise TransportEOF(self.name) from None
                raise TransportError(f"{self.name}: {exc}") from None
            if not data:
                raise TransportEOF(self.name)
        t = self.clock.now()  # stamp, then look (see SerialTransport._read)
        if not select.select([self.fd], [], [], 0)[0]:
            self.caught_up_to = t
        return [Chunk(self.name, t, data)] if data else []

    def _close(self) -> None:
        pass
