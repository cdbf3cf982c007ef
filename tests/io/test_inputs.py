"""The input registry: one spec syntax, one factory, the older options as spellings of specs,
one module per kind imported only when used; and the command lines that use it."""

import argparse
import dataclasses
import json
import subprocess
import sys

import pytest

from pfdoa.clock import FakeClock
from pfdoa.errors import InputError
from pfdoa.gateway import inputs
from pfdoa.gateway.inputs import InputContext, InputSpec, make_input, make_inputs, specs_from_args
from pfdoa.gateway.transports import Transport

import gateway_feed as feed

pytestmark = pytest.mark.io
PY = sys.executable


def test_every_registered_kind_is_one_module_with_its_named_class():
    seen = set()
    for kind, (module, name, help_line) in inputs.BACKENDS.items():
        cls = inputs.backend(kind)
        assert cls.__name__ == name and cls.__module__ == module and issubclass(cls, Transport)
        assert callable(getattr(cls, "from_spec", None)), kind
        assert help_line.startswith(kind), help_line  # the syntax first, for --help
        seen.add(module)
    assert len(seen) == len(inputs.BACKENDS) >= 5
    with pytest.raises(InputError, match="unknown input kind 'nope'"):
        inputs.backend("nope")


def test_the_registry_imports_no_input_module_until_a_spec_names_it():
    code = ("import sys, pfdoa.gateway.inputs as r; before = sorted(m for m in sys.modules if m.startswith("
            "'pfdoa.gateway.inputs.') or m in ('can', 'serial', 'paho')); r.make_input('serial:loop://'); "
            "print(before, 'pfdoa.gateway.inputs.serial' in sys.modules, 'pfdoa.gateway.inputs.can' in sys.modules)")
    out = subprocess.run([PY, "-c", code], capture_output=True, text=True, timeout=60, check=True).stdout.split()
    assert out == ["[]", "True", "False"]


@pytest.mark.parametrize("text, cls, attrs", [
    ("serial:/dev/ttyACM0@921600", "SerialTransport", {"url": "/dev/ttyACM0", "baudrate": 921600, "name": "serial0"}),
    ("serial:/dev/ttyACM0", "SerialTransport", {"url": "/dev/ttyACM0", "baudrate": 57600}),  # the context's baud
    ("serial:rfc2217://10.0.0.7:4000", "SerialTransport", {"url": "rfc2217://10.0.0.7:4000", "baudrate": 57600}),
    ("serial:socket://h:4000@9600", "SerialTransport", {"url": "socket://h:4000", "baudrate": 9600}),
    ("serial:loop://", "SerialTransport", {"url": "loop://"}),
    ("can:socketcan:can0", "CanTransport", {"kwargs": {"interface": "socketcan", "channel": "can0"}, "name": "can0"}),
    ("can:slcan:/dev/ttyACM0@500000,sleep_after_open=2", "CanTransport",
     {"kwargs": {"interface": "slcan", "channel": "/dev/ttyACM0", "bitrate": 500000, "sleep_after_open": 2}}),
    ("stdin", "StdinTransport", {"name": "stdin", "reads_stdin": True, "finite": True}),
    ("capture:run.cap", "CaptureReader", {"path": "run.cap", "files": ("run.cap",), "realtime": True}),
    ("capture:-", "CaptureReader", {"path": "-", "files": (), "reads_stdin": True}),
])
def test_a_spec_makes_its_input_and_opens_nothing(text, cls, attrs):
    clock = FakeClock()
    t = make_input(text, InputContext(clock=clock, serial_baud=57600, realtime=True))
    assert type(t).__name__ == cls and not t.is_open and t.clock is clock and t.where == f"--input {text}"
    for k, v in attrs.items():
        assert getattr(t, k) == v, k


@pytest.mark.parametrize("text, words", [
    ("nonsense:x", "--input nonsense:x: unknown input kind 'nonsense' (known: serial, can, stdin, capture, mqtt"),
    ("/dev/ttyACM0", "unknown input kind '/dev/ttyACM0'"),
    ("serial", "--input serial: expected serial:URL[@BAUD]"),
    ("serial:", "--input serial:: expected serial:URL[@BAUD]"),
    ("can:nonsense", "--input can:nonsense: expected INTERFACE:CHANNEL[@BITRATE]"),
    ("can:virtual:vc0,flag", "--input can:virtual:vc0,flag: option 'flag' is not key=value"),
    ("stdin:x", "--input stdin:x: stdin takes no argument"),
    ("capture:", "--input capture:: expected capture:FILE"),
    ("mqtt:nope", "--input mqtt:nope: expected mqtt:frames or mqtt:espresense"),
    ("mqtt:frames", "--input mqtt:frames: needs a broker"),
])
def test_a_bad_spec_is_one_input_error_naming_it(text, words):
    with pytest.raises(InputError) as exc:
        make_input(text)
    msg = str(exc.value)
    assert words in msg and "\n" not in msg and exc.value.exit_code == 2
    if text.startswith("/"):
        assert msg.endswith("; a serial port is serial:/dev/ttyACM0")


def test_the_older_options_are_spellings_of_specs():
    args = argparse.Namespace(serial=["/dev/ttyUSB0", "/dev/ttyUSB1@921600"], can=["virtual:vc0"], stdin=True,
                              replay_capture=[], mqtt_input=["frames"],
                              input=["serial:/dev/ttyUSB2", "can:socketcan:can1"])
    specs = specs_from_args(args)
    assert [(s.kind, s.arg, s.where()) for s in specs] == [
        ("serial", "/dev/ttyUSB0", "--serial /dev/ttyUSB0"), ("serial", "/dev/ttyUSB1@921600", "--serial /dev/ttyUSB1@921600"),
        ("can", "virtual:vc0", "--can virtual:vc0"), ("stdin", "", "--stdin"), ("mqtt", "frames", "--mqtt-input frames"),
        ("serial", "/dev/ttyUSB2", "--input serial:/dev/ttyUSB2"), ("can", "socketcan:can1", "--input can:socketcan:can1")]
    made = make_inputs([s for s in specs if s.kind != "mqtt"], InputContext(serial_baud=115200))
    assert [(type(t).__name__, t.name) for t in made] == [
        ("SerialTransport", "serial0"), ("SerialTransport", "serial1"), ("CanTransport", "can0"),
        ("StdinTransport", "stdin"), ("SerialTransport", "serial2"), ("CanTransport", "can1")]
    assert [t.baudrate for t in made if type(t).__name__ == "SerialTransport"] == [115200, 921600, 115200]
    # An older option keeps its own words in messages; an --input says its spec.
    assert made[0].where == "--serial /dev/ttyUSB0" and made[4].where == "--input serial:/dev/ttyUSB2"
    old = make_input(InputSpec("serial", "/dev/x@9600", "/dev/x@9600", "--serial"))
    new = make_input("serial:/dev/x@9600")
    assert (type(old), old.url, old.baudrate) == (type(new), new.url, new.baudrate)


def test_the_broker_inputs_connect_when_they_open():
    """mqtt:KIND is made at once but takes its subscription from the context when it opens
    (the broker connection is the MQTT output's, which exists only later)."""
    made = []

    class Sub:
        kind = "frames"

        def start(self):
            made.append("start")

        def stop(self):
            made.append("stop")

        def counters(self):
            return {"messages": 3}

    t = make_input("mqtt:frames", InputContext(mqtt=lambda kind: made.append(kind) or Sub()))
    assert type(t).__name__ == "FrameTransport" and t.name == "mqtt-frames" and made == [] and t.counters() == {}
    with t:
        assert made == ["frames", "start"] and t.counters() == {"messages": 3}
    assert made[-1] == "stop"


def _cli(*args, **kw):
    return subprocess.run([PY, "-m", "pfdoa", "-q", *args], capture_output=True, timeout=60, **kw)


@pytest.mark.parametrize("argv, words", [
    (["--input", "nonsense:x"], "--input nonsense:x: unknown input kind 'nonsense'"),
    (["--input", "serial:"], "--input serial:: expected serial:URL[@BAUD]"),
    (["--input", "capture:-", "--replay-capture", "-"], "standard input can be read once (--replay-capture -, "
                                                         "--input capture:-)"),
    (["--input", "capture:x.cap", "--input", "serial:loop://"], "cannot be mixed with live inputs (--input "
                                                                  "serial:loop://)"),
])
def test_a_bad_gateway_input_is_one_line_and_exit_2(site_file, argv, words):
    r = _cli("gateway", "--config", str(site_file()), *argv, "--wait-for-device", "0", input=b"")
    err = r.stderr.decode().strip().splitlines()
    assert r.returncode == 2 and len(err) == 1 and words in err[0], r.stderr.decode()[-2000:]


def test_help_states_the_spec_syntax_of_every_kind():
    out = subprocess.run([PY, "-m", "pfdoa", "gateway", "--help"], capture_output=True, text=True, timeout=60).stdout
    assert "--input SPEC" in out and "input specs" in out
    flat = " ".join(out.split())
    for _, _, line in inputs.BACKENDS.values():
        assert " ".join(line.split()) in flat, line
    out = subprocess.run([PY, "-m", "pfdoa", "anchors", "list", "--help"], capture_output=True, text=True,
                         timeout=60).stdout
    assert "--input SPEC" in out


def test_input_capture_is_replay_capture(site_file, tmp_path):
    """The same capture through --input capture:FILE and --replay-capture FILE: the same
    estimates, byte for byte, and the same final counters but the run time."""
    from pfdoa.gateway.inputs.capture import CAPTURE_V1, capture_line
    from pfdoa.gateway.transports import Chunk
    from pfdoa.protocol.uart import encode_uart

    cap = tmp_path / "run.cap"
    cap.write_text(CAPTURE_V1 + "\n" + "".join(
        capture_line(Chunk("serial0", 1_700_000_000.0 + 0.02 * seq, encode_uart(m, a)))
        for seq in range(60) for a, m in feed.reports(seq)))
    outs = []
    for argv in (["--input", f"capture:{cap}"], ["--replay-capture", str(cap)]):
        r = _cli("gateway", "--config", str(site_file()), *argv, "--method", "wcl", "--seed", "1",
                 "--stats", str(tmp_path / "s.json"))
        assert r.returncode == 0, r.stderr.decode()[-2000:]
        stats = json.loads((tmp_path / "s.json").read_text())
        stats.pop("seconds")
        outs.append((r.stdout, stats))
    assert outs[0] == outs[1] and len(outs[0][0].splitlines()) == 60
    assert outs[0][1]["inputs"] == {str(cap): {"bad_lines": 0, "time_jumps": 0}}


def test_anchors_takes_specs_and_refuses_inputs_that_are_not_one_link():
    for argv, words in ((["set", "--input", "stdin", "--anchor", "1"], "--input stdin is not bidirectional"),
                        (["list", "--input", "capture:x.cap"], "--input capture:x.cap: pfdoa anchors needs inputs "
                                                              "that are one link"),
                        (["list", "--input", "bogus"], "unknown input kind 'bogus'")):
        r = _cli("anchors", *argv)
        err = r.stderr.decode().strip().splitlines()
        assert r.returncode == 2 and len(err) == 1 and words in err[0], r.stderr.decode()


def test_health_carries_every_inputs_counters():
    """An input's counters (what it rejected) are in every health snapshot: the JSON by
    input name, the line as the inputs' rejections."""
    from pfdoa.gateway.health import Health
    from pfdoa.gateway.reassembly import SeqReassembler

    snap = Health().sampler(SeqReassembler([0, 1])).sample(1.0, 1.0)
    snap = dataclasses.replace(snap, inputs={"udp0": {"datagrams": 9, "rejected": {"oversized": 2, "bad_crc": 3}},
                                             "serial0": {"rejected": 0}})
    assert snap.to_json()["inputs"]["udp0"]["rejected"] == {"oversized": 2, "bad_crc": 3}
    assert snap.line().endswith("| inputs rejected udp0=5")


# -- the one pipeline builder -----------------------------------------------------------------

def test_one_builder_states_the_data_path_and_routes_beacons_by_strategy(site_file, tmp_path):
    from pfdoa.gateway.beacons import BeaconReading, FrameBeacons
    from pfdoa.gateway.reassembly import Reading
    from pfdoa.gateway.runner import Runner
    from pfdoa.gateway.setup import ROUTES, FramesRoute, SingleRoute, build_pipeline, load_settings

    assert ROUTES == {"frames": FramesRoute, "single": SingleRoute}
    st = load_settings(str(site_file("[gateway]\nmode = \"window\"\n")), str(tmp_path / "never.jsonl"))
    got = []

    class Records:
        def write(self, rec):
            got.append((rec.beacon, rec.t))

        def close(self):
            got.append("closed")

    frames = build_pipeline(st, method="wcl", seed=1, named_beacons=True, writer=Records())
    assert isinstance(frames.gateway.beacons, FrameBeacons) and frames.gateway.named is not None
    single = build_pipeline(st, method="wcl", seed=1, frames=False, beacon="tag", writer=Records())
    assert single.gateway.beacons is None and single.gateway.named is None
    # Named beacons' readings reach their own estimator; the records go to the writer given
    # (no output file is opened), named.
    for k in range(3):
        for a in (0, 1, 2, 3):
            frames.gateway.push_beacon(BeaconReading("dev1", Reading(a, -50.0 - a, 10.0 + k)))
        frames.gateway.poll(11.0 + k)
    frames.gateway.finish()
    frames.close()
    assert got[-1] == "closed" and {b for b, _ in got[:-1]} == {"dev1"} and len(got) > 1
    assert not (tmp_path / "never.jsonl").exists()
    run = frames.runner([], clock=FakeClock())
    assert isinstance(run, Runner) and run.gateway is frames.gateway and run.localizer is frames.localizer


def test_the_simulator_and_the_bench_build_their_pipeline_with_the_one_builder():
    """The fleet simulator and its benchmark take the gateway's chain from build_pipeline,
    not from its parts (no Gateway, tracker, localizer or grouper of their own)."""
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    parts = {"Gateway", "BeaconTracker", "FrameBeacons", "Localizer", "build_named_tracker", "beacon_localizers",
             "make_grouper", "WindowGrouper", "SeqReassembler"}
    for rel in ("sim/pfdoasim/fleet.py", "bench/fleet.py"):
        tree = ast.parse((root / rel).read_text())
        imported = {a.asname or a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)
                    and (n.module or "").startswith("pfdoa.gateway") for a in n.names}
        assert "build_pipeline" in imported and not imported & parts, (rel, imported & parts)
