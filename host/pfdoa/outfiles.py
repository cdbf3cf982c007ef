"""Opening the files the product writes: one path for every output (docs/security.md).

Two kinds of output, and what each does with what is already at its path:

* **whole files** (:func:`write_whole`: ``--stats``, ``pfdoa calibrate --out``, ``pfdoa
  eval --out`` and its plots, the simulator's site file and summaries). A regular file (or
  a path not there yet) is written atomically: a temporary file beside it, flushed to disk,
  renamed over it with the old file's permissions (and owner, when run as root), so a
  reader, a signal or a full disk in between sees the old file or the new one, never half.
* **streams** (:func:`open_stream`: ``--out``, ``--capture``, ``--readings-out``,
  ``--health-json``, ``--record``, the simulator's trace), written as the run goes.
  ``existing="replace"`` (a replay, the simulator: a function of its inputs) truncates a
  regular file; ``existing="keep"`` (``pfdoa gateway``, a service that may be restarted)
  appends to a regular file whose first line says it is the same kind of file
  (``same_kind``), and moves any other non-empty file aside to ``PATH.N`` (the first free
  N) with one log line: a restarted gateway never wipes what its previous run wrote.

For both: anything that is not a regular file (a character or block device, a FIFO) is
written through, opened as it is: never created, truncated, renamed over or replaced, so
``--stats /dev/null`` as root leaves /dev/null a device. A symbolic link is followed (the
file it names is written; the link stays a link). A FIFO that nobody reads yet gets one
line, "waiting for a reader on PATH", and the wait ends on SIGINT/SIGTERM
(:func:`pfdoa.signals.interruptible`). A path that is a directory is refused. Every
failure to open, write or close is :class:`~pfdoa.errors.OutputError` naming the option
and the path (exit status 1). That an output is not also an input of the run is checked
before anything is opened (:func:`pfdoa.commands._common.check_outputs`, by device and
inode, standard input included).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import io
import logging
import os
import secrets
import stat
import sys
import time
from typing import IO, Callable

from pfdoa import signals
from pfdoa.errors import InputError, Interrupted, OutputError

log = logging.getLogger(__name__)

EXISTING = ("replace", "keep")
FIFO_POLL_S = 0.05  # how often a FIFO without a reader is tried again
MAX_ASIDE = 1000  # PATH.1 .. PATH.999: beyond that the old files are the user's to tidy


def _why(exc: BaseException) -> str:
    return getattr(exc, "strerror", None) or str(exc)


def _label(what: str, path: str) -> str:
    return f"{what} {path}" if what else path


def _stat(path: str) -> os.stat_result | None:
    try:
        return os.stat(path)  # follows symbolic links: the file that would be written
    except FileNotFoundError:
        return None


def _open_through(path: str, what: str, flags: int) -> int:
    """Open an existing non-regular file for writing as it is. A FIFO without a reader:
    say so once and wait for one (SIGINT/SIGTERM end the wait)."""
    try:
        return os.open(path, flags | os.O_NONBLOCK)
    except OSError as exc:
        if exc.errno != errno.ENXIO or not stat.S_ISFIFO(os.stat(path).st_mode):
            raise
    log.warning("%s: waiting for a reader on %s", what or "output", path)
    try:
        with signals.interruptible():
            # Polled, not a blocking open(): a process with other threads (a pool's, the
            # gateway's readers) may take the signal on one of them, which would leave a
            # blocking open() in this thread uninterrupted; the handler runs between polls.
            while True:
                try:
                    return os.open(path, flags | os.O_NONBLOCK)
                except OSError as exc:
                    if exc.errno != errno.ENXIO:
                        raise
                time.sleep(FIFO_POLL_S)
    except Interrupted as exc:
        raise Interrupted(exc.signum, f"{exc} while waiting for a reader on {path}") from None


def _blocking(fd: int) -> int:
    fl = fcntl.fcntl(fd, fcntl.F_GETFL)
    if fl & os.O_NONBLOCK:
        fcntl.fcntl(fd, fcntl.F_SETFL, fl & ~os.O_NONBLOCK)
    return fd


def open_fd(path: str, what: str, *, existing: str = "replace",
            same_kind: Callable[[bytes], bool] | None = None) -> tuple[int, bool]:
    """Open ``path`` as a stream output (see the module doc); (descriptor, fresh), where
    ``fresh`` says that the stream starts empty (a header belongs at its start)."""
    if existing not in EXISTING:
        raise ValueError(f"existing must be one of {EXISTING}")
    label = _label(what, path)
    try:
        st = _stat(path)
        if st is not None and stat.S_ISDIR(st.st_mode):
            raise IsADirectoryError(errno.EISDIR, "Is a directory")
        if st is not None and not stat.S_ISREG(st.st_mode):
            return _blocking(_open_through(path, what, os.O_WRONLY)), True
        if st is None or st.st_size == 0:
            return os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666), True
        if existing == "replace":
            return os.open(path, os.O_WRONLY | os.O_TRUNC), True
        if same_kind is not None and same_kind(_first_line(path)):
            return os.open(path, os.O_WRONLY | os.O_APPEND), False
        real = os.path.realpath(path)  # a link stays a link: the file it names moves aside
        aside = _move_aside(real)
        log.warning("%s: the file there is not one this run can continue: kept as %s", label, aside)
        return os.open(real, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), True
    except (OSError, ValueError) as exc:  # ValueError: a NUL in the path
        raise OutputError(f"{label}: cannot write: {_why(exc)}") from None


def open_stream(path: str, what: str, *, existing: str = "replace", binary: bool = False,
                same_kind: Callable[[bytes], bool] | None = None) -> tuple[IO, bool]:
    """:func:`open_fd` as a file object (text: UTF-8, no newline translation)."""
    fd, fresh = open_fd(path, what, existing=existing, same_kind=same_kind)
    if binary:
        return os.fdopen(fd, "wb"), fresh
    return os.fdopen(fd, "w", encoding="utf-8", newline=""), fresh


def _first_line(path: str, limit: int = 4096) -> bytes:
    with open(path, "rb") as fh:
        return fh.readline(limit).rstrip(b"\r\n")


def _move_aside(real: str) -> str:
    for n in range(1, MAX_ASIDE):
        aside = f"{real}.{n}"
        if not os.path.lexists(aside):
            os.rename(real, aside)
            return aside
    raise FileExistsError(errno.EEXIST, f"{real}.1 .. .{MAX_ASIDE - 1} all exist")


def write_whole(path: str | os.PathLike, data: str | bytes, what: str = "") -> None:
    """Write a whole output (see the module doc): atomically for a regular file, through
    for anything else. Raises :class:`~pfdoa.errors.OutputError` naming ``what``."""
    target = os.fspath(path)
    label = _label(what, target)
    raw = data.encode("utf-8") if isinstance(data, str) else data
    try:
        st = _stat(target)
        if st is not None and stat.S_ISDIR(st.st_mode):
            raise IsADirectoryError(errno.EISDIR, "Is a directory")
        if st is not None and not stat.S_ISREG(st.st_mode):
            fd = _blocking(_open_through(target, what, os.O_WRONLY))
            with os.fdopen(fd, "wb") as fh:
                fh.write(raw)
            return
    except (OSError, ValueError) as exc:
        raise OutputError(f"{label}: cannot write: {_why(exc)}") from None
    _replace_atomically(os.path.realpath(target), raw, label, st)


def _replace_atomically(real: str, raw: bytes, label: str, st: os.stat_result | None) -> None:
    tmp = os.path.join(os.path.dirname(real) or ".",
                       f".{os.path.basename(real)}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    except (OSError, ValueError) as exc:
        raise OutputError(f"{label}: cannot write: {_why(exc)}") from None
    done = False
    try:
        if st is not None:  # the old file's permissions (and, as root, its owner)
            os.fchmod(fd, st.st_mode & 0o7777)
            if os.geteuid() == 0:
                with contextlib.suppress(OSError):
                    os.fchown(fd, st.st_uid, st.st_gid)
        with os.fdopen(fd, "wb") as fh:
            fh.write(raw)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, real)
        done = True
    except OSError as exc:
        raise OutputError(f"{label}: cannot write: {_why(exc)}") from None
    finally:  # an error or a signal on the way: the old file stays, the temporary goes
        if not done:
            with contextlib.suppress(OSError):
                os.unlink(tmp)


def write_stdout(text: str, what: str = "standard output") -> None:
    """A command's product on standard output; a failure is one OutputError line (a broken
    pipe is the reader's choice to stop reading, as for every write to standard output)."""
    if sys.stdout is None:
        raise InputError(f"{what}: standard output is closed")
    try:
        sys.stdout.write(text)
        sys.stdout.flush()
    except BrokenPipeError:
        raise
    except (OSError, ValueError) as exc:
        raise OutputError(f"{what}: cannot write: {_why(exc)}") from None


@contextlib.contextmanager
def stdout_guard(what: str = "standard output"):
    """Lines printed inside reach standard output or end the command with one
    OutputError line (``print`` raising OSError on ``> /dev/full``)."""
    try:
        yield
        if sys.stdout is not None:
            sys.stdout.flush()
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise OutputError(f"{what}: cannot write: {_why(exc)}") from None


def figure_bytes(fig, path: str | os.PathLike, **kw) -> bytes:
    """A matplotlib figure as the bytes of the file ``path`` names (its suffix is the
    format, PNG without one), for :func:`write_whole`."""
    buf = io.BytesIO()
    fig.savefig(buf, format=os.path.splitext(os.fspath(path))[1][1:].lower() or "png", **kw)
    return buf.getvalue()
