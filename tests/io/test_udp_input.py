"""udp:[HOST:]PORT with real datagrams on the loopback and an injected clock: each sender its
own stream, bounded senders, idle ones let go, noise never holding a place, every
rejection counted; and through the real pfdoa gateway process: four Wi-Fi anchors (one
of them restarting on a new port, one going silent and coming back on its port) and a
thousand one-off senders of noise."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pfdoa.clock import FakeClock
from pfdoa.errors import InputError
from pfdoa.gateway.inputs import InputContext, make_input
from pfdoa.gateway.inputs.udp import MAX_DATAGRAM, MAX_SENDERS, SENDER_IDLE_S, parse_address
from pfdoa.gateway.transports import TransportFatal
from pfdoa.protocol.messages import ConfigSet
from pfdoa.protocol.uart import StreamDecoder, encode_uart

import gateway_feed as feed

pytestmark = pytest.mark.io
PY = sys.executable
FEED = str(Path(__file__).resolve().parents[1] / "gateway_feed.py")
WAIT_S = 60.0  # bounds a hang only: every wait below is for an observable result


def frames(seq: int, anchors=(0, 1, 2, 3)) -> dict[int, bytes]:
    return {a: encode_uart(m, a) for a, m in feed.reports(seq) if a in anchors}


@pytest.mark.parametrize("arg, expected", [
    ("5000", ("0.0.0.0", 5000)), ("127.0.0.1:5000", ("127.0.0.1", 5000)), ("[::1]:5000", ("::1", 5000)),
    ("anchors.lan:65535", ("anchors.lan", 65535)),
])
def test_the_address_of_a_spec(arg, expected):
    assert parse_address(arg, "--input udp:" + arg) == expected


@pytest.mark.parametrize("arg", ["", "x", "0", "70000", "127.0.0.1:", "::1:5000", "[::1:5000", ":5000x"])
def test_a_bad_address_is_one_line(arg):
    with pytest.raises(InputError, match=r"^--input udp:.*: expected udp:\[HOST:\]PORT, a port in 1..65535"):
        make_input("udp:" + arg)


def test_the_docs_state_the_bounds_of_the_code():
    docs = Path(__file__).resolve().parents[2] / "docs"
    doc = " ".join((docs / "gateway.md").read_text().split())
    for text in (f"a datagram above {MAX_DATAGRAM} bytes is dropped", f"at most {MAX_SENDERS} senders are tracked",
                 f"a sender silent for {SENDER_IDLE_S:g} s is let go", f"per tracked UDP sender (≤ {MAX_SENDERS} per"):
        assert text in doc, text
    doc = " ".join((docs / "security.md").read_text().split())
    for text in (f"{MAX_SENDERS} per input (`MAX_SENDERS`)", f"a datagram <= {MAX_DATAGRAM} bytes (`MAX_DATAGRAM`)",
                 f"a sender silent {SENDER_IDLE_S:g} s let go"):
        assert text in doc, text


class Link:
    """A UdpTransport on 127.0.0.1 with a fake clock, and senders that are real sockets."""

    def __init__(self):
        self.clock = FakeClock()
        self.t = make_input(f"udp:127.0.0.1:{_free_port()}", InputContext(clock=self.clock)).open()
        self.dest = ("127.0.0.1", self.t.port)
        self.chunks = []

    def sender(self):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        return s

    def send(self, s, data: bytes) -> None:
        s.sendto(data, self.dest)

    def until(self, datagrams: int) -> dict:
        """Read until the input has taken ``datagrams`` datagrams in all; its counters."""
        end = time.monotonic() + WAIT_S
        while self.t.counters()["datagrams"] < datagrams:
            assert time.monotonic() < end, self.t.counters()
            self.chunks += self.t.read(0.5)
        return self.t.counters()

    def decoded(self) -> list[int]:
        dec = StreamDecoder()
        assert {c.source for c in self.chunks} <= {self.t.name}
        return [d.anchor_id for c in self.chunks for d in dec.feed(c.data)]


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def link():
    ln = Link()
    yield ln
    ln.t.close()


def test_each_sender_is_its_own_stream(link):
    """A frame split over two datagrams of one sender, another sender's datagram between
    them: both whole; what goes on is whole valid frames only, under the input's name."""
    a, b = link.sender(), link.sender()
    f = frames(1)
    link.send(a, f[0][:9])
    link.send(b, f[1] + f[2])
    link.send(a, f[0][9:] + f[3])
    c = link.until(3)
    assert sorted(link.decoded()) == [0, 1, 2, 3]
    assert all(ch.data.endswith(b"\x00") for ch in link.chunks)
    assert c["frames"] == 4 and c["rejected"] == {} and c["senders"] == 2
    assert {k: v["frames"] for k, v in c["per_sender"].items()} == {
        f"127.0.0.1:{a.getsockname()[1]}": 2, f"127.0.0.1:{b.getsockname()[1]}": 2}
    assert link.t.caught_up_to is not None  # nothing more was waiting


def test_every_rejection_is_counted_per_kind_and_per_sender(link):
    a = link.sender()
    f = frames(2)
    bad_crc = bytearray(f[1])
    bad_crc[-2] ^= 0x01  # a CRC bit of the trailer
    host_to_anchor = encode_uart(ConfigSet(7), 3)
    link.send(a, b"\x17garbage\x00" + f[0])  # a bad frame before a good one
    link.send(a, bytes(bad_crc) + host_to_anchor)
    link.send(a, b"\x01" * (MAX_DATAGRAM + 1))  # oversized: dropped unread
    link.send(a, b"\x05" * 200 + b"\x00" + f[2])  # an overlong frame, then a good one
    c = link.until(4)
    assert sorted(link.decoded()) == [0, 2]
    assert c["rejected"] == {"bad_cobs": 1, "bad_crc": 1, "oversized": 1, "overlong": 1, "unknown_type": 1}
    (mine,) = c["per_sender"].values()
    assert mine == {"datagrams": 3, "frames": 2, "bad_frames": 4}  # the oversized one never reached it


def test_noise_never_keeps_an_anchor_out_and_idle_senders_go(link):
    """MAX_SENDERS one-off senders of noise fill the table; an anchor still gets in (the
    least recently heard noise makes room). Once every place holds a sender of valid frames,
    a new one is refused and counted, until the others fall silent for SENDER_IDLE_S of the
    injected clock."""
    noise = [link.sender() for _ in range(MAX_SENDERS)]
    for s in noise:
        link.send(s, os.urandom(40) + b"\x00")
    c = link.until(MAX_SENDERS)
    assert c["senders"] == MAX_SENDERS and c["senders_evicted"] == 0
    anchors = [link.sender() for _ in range(MAX_SENDERS)]
    for i, s in enumerate(anchors):
        link.send(s, frames(i)[i % 4])
    c = link.until(2 * MAX_SENDERS)
    assert c["senders_evicted"] == MAX_SENDERS and c["frames"] == MAX_SENDERS and c["senders"] == MAX_SENDERS
    assert all(v["frames"] == 1 for v in c["per_sender"].values())  # only anchors hold places now
    late = link.sender()
    link.send(late, frames(99)[0])
    c = link.until(2 * MAX_SENDERS + 1)
    assert c["rejected"]["no_room"] == 1 and c["frames"] == MAX_SENDERS
    link.clock.advance(SENDER_IDLE_S)
    link.send(late, frames(100)[0])
    c = link.until(2 * MAX_SENDERS + 2)
    assert c["senders_idle"] == MAX_SENDERS and c["senders"] == 1 and c["frames"] == MAX_SENDERS + 1
    for s in noise + anchors + [late]:
        s.close()


def test_a_port_in_use_is_fatal_with_one_line():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1]
        t = make_input(f"udp:127.0.0.1:{port}")
        with pytest.raises(TransportFatal) as exc:
            t.open()
    assert str(exc.value) == f"--input udp:127.0.0.1:{port}: cannot receive there: the port is in use"
    assert exc.value.exit_code == 2


# -- through the real gateway process ------------------------------------------------------

def _estimates(path: Path) -> list[dict]:
    try:
        text = path.read_text()
    except FileNotFoundError:
        return []
    return [json.loads(ln) for ln in text.splitlines() if ln.endswith("}")]


def _udp_health(path: Path) -> dict:
    """The input's counters in the latest health snapshot (--health-json)."""
    try:
        lines = [ln for ln in path.read_text().splitlines() if ln.endswith("}")]
    except FileNotFoundError:
        return {}
    return json.loads(lines[-1]).get("inputs", {}).get("udp0", {}) if lines else {}


def _wait(what: str, pred, proc) -> None:
    end = time.monotonic() + WAIT_S
    while not pred():
        assert proc.poll() is None, f"the gateway exited ({proc.returncode}) waiting for {what}"
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.02)


def test_four_wifi_anchors_a_restart_and_a_thousand_senders_of_noise(site_file, tmp_path):
    port = _free_port()
    out, health, stats, err = (tmp_path / n for n in ("est.jsonl", "health.jsonl", "stats.json", "gateway.log"))
    gw = subprocess.Popen([PY, "-m", "pfdoa", "gateway", "--config", str(site_file()), "--input",
                           f"udp:127.0.0.1:{port}", "--method", "wcl", "--seed", "1", "--out", str(out),
                           "--health", "0.1", "--health-json", str(health), "--stats", str(stats)],
                          stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=open(err, "wb"))
    fd = subprocess.Popen([PY, FEED, "udp", f"127.0.0.1:{port}", "600"], stdin=subprocess.PIPE,
                          stdout=subprocess.PIPE, text=True)
    try:
        ports = [int(p) for p in fd.stdout.readline().split()[1:]]
        assert len(ports) == 4

        def whole_after(n0: int, n: int = 20):
            """``n`` estimates after the first ``n0``, each from all four anchors."""
            def ok():
                recs = _estimates(out)[n0:]
                return len(recs) >= n and all(r["anchors"] == [0, 1, 2, 3] for r in recs[-n:])
            return ok

        def command(line: str) -> list[str]:
            """Tell the anchors; what they said until it was done (their next datagram sent)."""
            fd.stdin.write(line + "\n")
            fd.stdin.flush()
            said = [fd.stdout.readline()]
            while said[-1].endswith("\n") and not said[-1].startswith("ok"):
                said.append(fd.stdout.readline())
            assert said[-1].startswith("ok"), f"the anchors ended: {said}"
            return [ln.strip() for ln in said]

        _wait("estimates from the four anchors", whole_after(0), gw)
        # Anchor 1's board restarts: its datagrams come from a new source port.
        (new,) = [int(ln.split()[2]) for ln in command("restart 1") if ln.startswith("port 1 ")]
        assert new != ports[1]
        _wait("the restarted anchor's frames", lambda: _udp_health(health).get("per_sender", {}).get(
            f"127.0.0.1:{new}", {}).get("frames", 0) > 0, gw)
        _wait("whole sets after the restart", whole_after(len(_estimates(out))), gw)
        # Anchor 2 falls silent, then sends again from the same port.
        command("pause 2")
        _wait("sets without anchor 2", lambda: sum(r["missing"] == [2] for r in _estimates(out)) >= 5, gw)
        command("resume 2")
        _wait("whole sets after anchor 2 came back", whole_after(len(_estimates(out))), gw)

        # A thousand one-off senders of noise, in batches the gateway is seen to take. Each
        # from an address of its own (127.1.X.Y: all of 127/8 is this host's loopback), so no
        # two share a sender's place however the kernel hands out ports.
        before = _udp_health(health)
        n_oversized = sent = 0
        rng = np.random.default_rng(7)
        for batch in range(20):
            for k in range(50):
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                s.bind((f"127.1.{batch}.{k + 1}", 0))
                if k == 0:
                    data, n_oversized = b"\x01" * (MAX_DATAGRAM + 10), n_oversized + 1
                else:
                    data = rng.integers(0, 256, size=int(rng.integers(8, 300)), dtype=np.uint8).tobytes() + b"\x00"
                s.sendto(data, ("127.0.0.1", port))
                s.close()
                sent += 1

            def taken(sent=sent):
                h = _udp_health(health)
                return (h.get("senders_admitted", 0) + h.get("rejected", {}).get("oversized", 0)
                        + h.get("kernel_drops", 0)) >= (before["senders_admitted"] + sent)
            _wait(f"the gateway to take {sent} senders of noise", taken, gw)
        n0 = len(_estimates(out))
        _wait("whole sets after the noise", whole_after(n0), gw)
    finally:
        fd.stdin.write("stop\n")
        fd.stdin.close()
        fd.wait(timeout=30)
        if gw.poll() is None:
            os.kill(gw.pid, signal.SIGINT)
        code = gw.wait(timeout=60)
    assert code == 128 + signal.SIGINT, err.read_text()[-2000:]
    c = json.loads(stats.read_text())
    udp = c["inputs"]["udp0"]
    # The noise was counted: each datagram either rejected before a sender was made
    # (oversized), or made a sender that took a noise sender's place; or the kernel says it
    # dropped it while the gateway was behind.
    drops = udp["kernel_drops"]
    assert n_oversized - drops <= udp["rejected"]["oversized"] <= n_oversized
    noise_senders = udp["senders_admitted"] - 5  # the four anchors and the restarted one's new port
    assert sent - n_oversized - drops <= noise_senders <= sent - n_oversized
    assert udp["senders_evicted"] >= sent - n_oversized - drops - MAX_SENDERS
    assert udp["senders"] <= MAX_SENDERS and udp["rejected"].get("no_room", 0) == 0
    # The anchors kept their places all along: each of the four still there, with its valid
    # frames and its bad ones (a garbage prefix every 10th beacon) counted on it.
    live = [f"127.0.0.1:{p}" for p in (ports[0], new, ports[2], ports[3])]
    for label in live:
        assert udp["per_sender"][label]["frames"] > 50 and udp["per_sender"][label]["bad_frames"] > 0, label
    assert udp["rejected"]["bad_cobs"] >= sum(udp["per_sender"][k]["bad_frames"] for k in live)
    recs = _estimates(out)
    assert all(r["anchors"] == [0, 1, 2, 3] for r in recs[-20:])
    assert c["estimates"] == len(recs) and c["errors"] == {}
