"""Inputs: one module per kind behind one registry, made from one spec syntax in one place.

As python-can lays out its interfaces: the base class is
:class:`pfdoa.gateway.transports.Transport` (``open``/``read``/``close``; a subclass
implements ``_open``/``_read``/``_close``), each kind of input is one module here with one
class, and :data:`BACKENDS` maps the kind to that module and class, imported only when a
spec names it (``--help`` loads none, and an optional dependency such as paho-mqtt is
needed only by who uses its input).

A spec is ``KIND[:ARGUMENT]``::

    serial:URL[@BAUD]      a serial port or any pyserial URL: serial:/dev/ttyACM0@115200,
                           serial:rfc2217://host:4000, serial:socket://host:4000, serial:loop://
    can:INTERFACE:CHANNEL[@BITRATE][,key=value...]   python-can: can:socketcan:can0,
                           can:slcan:/dev/ttyACM0@500000, can:virtual:vc0; can:config[:PATH]
    stdin                  the UART byte stream on standard input
    capture:FILE           a capture file replayed ('-': a timed stream on standard input)
    mqtt:frames            our frames on the broker of --mqtt, a topic per anchor
    mqtt:espresense        ESPresense nodes' messages on the broker of --mqtt
    udp:[HOST:]PORT        our frames in UDP datagrams, each sender its own stream (Wi-Fi anchors)

:func:`make_input` turns a spec into an input object (its class's ``from_spec``), and is the
one place ``pfdoa gateway`` and ``pfdoa anchors`` build their inputs: ``--input SPEC`` and
the older options, which are spellings of specs (:data:`SPELLINGS`: ``--serial URL`` is
``serial:URL``, ``--replay-capture FILE`` is ``capture:FILE``, ...). A bad spec is one
:class:`~pfdoa.errors.InputError` line naming the option (exit status 2); building an input
opens nothing.

A new kind of input is one module here (a Transport subclass with a ``from_spec``
classmethod) and one line in :data:`BACKENDS` (the ``mqtt`` kind's two message formats sit
beside it: :mod:`.mqtt_frames`, :mod:`.espresense`). What the commands ask of a class, besides
the Transport interface (class attributes, defaults on the base or here):

* ``from_spec(spec, ctx, index) -> Transport`` - the input for ``spec``; ``index`` counts
  the inputs of its kind before it (its name: ``serial0``, ``udp1``, ...);
* ``finite``, ``bidirectional``, ``is_can`` - as in the base class;
* ``decoder_sources`` - byte-stream sources it feeds the gateway's decoder table (1 for a
  serial port; 0 when it has its own bound or none);
* ``carries_frames`` - it delivers our protocol's frames (the site's ids must be wire ids);
* ``reads_stdin``, ``files`` - standard input read, files read (outputs may not be them).
"""

from __future__ import annotations

import importlib
import textwrap
from collections import Counter
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence

from pfdoa.clock import SYSTEM, Clock
from pfdoa.errors import InputError
from pfdoa.gateway.transports import Transport

# kind -> (module, class, "SYNTAX  what it is", for --help)
BACKENDS: dict[str, tuple[str, str, str]] = {
    "serial": ("pfdoa.gateway.inputs.serial", "SerialTransport",
               "serial:URL[@BAUD]  a serial port or pyserial URL (/dev/ttyACM0, rfc2217://HOST:PORT, "
               "socket://HOST:PORT, loop://)"),
    "can": ("pfdoa.gateway.inputs.can", "CanTransport",
            "can:INTERFACE:CHANNEL[@BITRATE][,key=value...]  a CAN bus through python-can (socketcan:can0, "
            "slcan:/dev/ttyACM0@500000, virtual:vc0), or can:config[:PATH]"),
    "stdin": ("pfdoa.gateway.inputs.stdin", "StdinTransport", "stdin  the UART byte stream on standard input"),
    "capture": ("pfdoa.gateway.inputs.capture", "CaptureReader",
                "capture:FILE  a capture file, replayed on its recorded times ('-': standard input)"),
    "mqtt": ("pfdoa.gateway.inputs.mqtt", "MqttTransport",
             "mqtt:frames | mqtt:espresense  our frames, or ESPresense nodes' messages, on the broker of --mqtt"),
    "udp": ("pfdoa.gateway.inputs.udp", "UdpTransport",
            "udp:[HOST:]PORT  our frames in UDP datagrams (Wi-Fi anchors), each sender its own stream; HOST "
            "default 0.0.0.0 (every interface)"),
}

# The older options, each a spelling of one kind of spec: (argparse dest, option, kind).
SPELLINGS: tuple[tuple[str, str, str], ...] = (
    ("serial", "--serial", "serial"), ("can", "--can", "can"), ("stdin", "--stdin", "stdin"),
    ("replay_capture", "--replay-capture", "capture"), ("mqtt_input", "--mqtt-input", "mqtt"))


@dataclass(frozen=True)
class InputSpec:
    """One input as the user gave it: ``kind`` and ``arg`` (what follows ``KIND:``), and
    ``option`` with ``text`` (its value) for messages."""

    kind: str
    arg: str
    text: str
    option: str = "--input"

    def where(self) -> str:
        """The input as the user named it: ``--input udp:5000``, ``--serial /dev/ttyACM0``."""
        return f"{self.option} {self.text}" if self.text else self.option


@dataclass
class InputContext:
    """What building an input may need besides its spec."""

    clock: Clock = SYSTEM
    serial_baud: int = 115200  # when a serial spec names none ([gateway] serial_baud)
    realtime: bool = False  # capture files paced by their recorded times
    espresense: Any = None  # the site's EspresenseConfig (mqtt:espresense)
    # kind ("frames", "espresense") -> an MqttInput on the broker connection, when one is
    # open (pfdoa.sinks.options.mqtt_input); called when the input opens.
    mqtt: Callable[[str], Any] | None = None


def kinds() -> tuple[str, ...]:
    return tuple(BACKENDS)


def parse_spec(text: str, option: str = "--input") -> InputSpec:
    """``KIND[:ARGUMENT]`` -> InputSpec; InputError (one line, exit 2) for an unknown kind."""
    kind, _, arg = text.partition(":")
    if kind not in BACKENDS:
        hint = f"; a serial port is serial:{text}" if text.startswith("/") or "://" in text else ""
        raise InputError(f"{option} {text}: unknown input kind {kind!r} (known: {', '.join(BACKENDS)}; e.g. "
                         f"serial:/dev/ttyACM0@115200, can:socketcan:can0){hint}")
    return InputSpec(kind, arg, text, option)


def specs_from_args(args: Any) -> list[InputSpec]:
    """The inputs a command's options name: the older spellings first (in :data:`SPELLINGS`
    order, as the commands always took them), then every ``--input``."""
    out: list[InputSpec] = []
    for dest, option, kind in SPELLINGS:
        value = getattr(args, dest, None)
        if value is True:
            out.append(InputSpec(kind, "", "", option))
        elif isinstance(value, list):
            out += [InputSpec(kind, v, v, option) for v in value]
    return out + [parse_spec(text) for text in getattr(args, "input", None) or ()]


def backend(kind: str) -> type[Transport]:
    """The class of an input kind, imported now (InputError for an unknown kind or a
    module that cannot be imported: a missing optional dependency)."""
    if kind not in BACKENDS:
        raise InputError(f"unknown input kind {kind!r} (known: {', '.join(BACKENDS)})")
    module, name, _ = BACKENDS[kind]
    try:
        mod = importlib.import_module(module)
    except ImportError as exc:
        raise InputError(f"input kind {kind!r}: {module} cannot be imported ({exc})") from None
    cls: type[Transport] = getattr(mod, name)
    return cls


def make_input(spec: InputSpec | str, ctx: InputContext | None = None, index: int = 0) -> Transport:
    """The input a spec names (a string is parsed as ``--input``'s), not yet opened."""
    if isinstance(spec, str):
        spec = parse_spec(spec)
    cls: Any = backend(spec.kind)
    return cls.from_spec(spec, ctx or InputContext(), index)


def make_inputs(specs: Iterable[InputSpec], ctx: InputContext | None = None) -> list[Transport]:
    """Every input of ``specs`` in order, each kind counted from 0 (``serial0``, ``serial1``)."""
    seen: Counter[str] = Counter()
    out = []
    for s in specs:
        out.append(make_input(s, ctx, seen[s.kind]))
        seen[s.kind] += 1
    return out


def decoder_sources(inputs: Sequence[Transport]) -> int:
    return sum(int(getattr(t, "decoder_sources", 0)) for t in inputs)


def reads_stdin(inputs: Sequence[Transport]) -> list[Transport]:
    return [t for t in inputs if getattr(t, "reads_stdin", False)]


def spec_lines(which: Iterable[str] = BACKENDS) -> str:
    """The spec syntax of ``which`` kinds for a command's --help: each syntax two spaces in,
    what it is wrapped below it."""
    out = []
    for k in which:
        syntax, _, what = BACKENDS[k][2].partition("  ")
        out += [f"  {syntax}", textwrap.fill(what, 88, initial_indent=" " * 6, subsequent_indent=" " * 6)]
    return "\n".join(out)
