"""The generated constants files match messages.json, and messages.json is self-consistent."""

import importlib.util
import json
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _gen():
    spec = importlib.util.spec_from_file_location("protocol_gen", ROOT / "protocol" / "gen.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_generated_files_are_up_to_date():
    gen = _gen()
    for path, text in gen.outputs().items():
        assert path.read_text() == text, f"{path} is stale: run python protocol/gen.py"


def test_check_mode_exits_zero():
    r = subprocess.run([sys.executable, str(ROOT / "protocol" / "gen.py"), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_validate_rejects_a_wrong_crc_extra():
    gen = _gen()
    d = json.loads(gen.SPEC_JSON.read_text())
    d["messages"][0]["crc_extra"] ^= 1
    try:
        gen.validate(d)
    except SystemExit as e:
        assert "crc_extra" in str(e)
    else:
        raise AssertionError("validate accepted a wrong crc_extra")


def test_python_defs_match_json():
    from pfdoa.protocol import defs

    d = json.loads((ROOT / "protocol" / "messages.json").read_text())
    assert defs.DEFS_HASH == d["defs_hash"]["2"] and defs.V1_DEFS_HASH == d["defs_hash"]["1"]
    assert defs.PROTO_VERSION == d["protocol_version"] and defs.VERSIONS == tuple(d["versions"])
    assert defs.ERRORS == tuple(d["errors"])
    for m in d["messages"]:
        key = m["name"] if 2 in m["versions"] else "V1_" + m["name"]
        assert getattr(defs, f"MSG_{key}") == m["type"]
        assert getattr(defs, f"MSG_{key}_CRC_EXTRA") == m["crc_extra"]
        assert defs.MESSAGES[key][4] == tuple((f["name"], f["type"]) for f in m["fields"])
    wire = [getattr(defs, f"ERR_{e.upper()}") for e in d["errors"]]
    assert wire == list(range(-1, -len(d["errors"]) - 1, -1))  # -1, -2, ... in SPEC 2.3 order
    assert [getattr(defs, f"ERR_{e.upper()}") for e in d["local_errors"]] == list(
        range(-len(d["errors"]) - 1, -len(d["errors"]) - len(d["local_errors"]) - 1, -1))


def test_c_header_and_micropython_defs_agree_with_python():
    from pfdoa.protocol import defs

    header = (ROOT / "firmware/core/include/pfdoa_defs.h").read_text()
    c_vals = {m.group(1): int(m.group(2).strip("()").rstrip("u"), 0)
              for m in re.finditer(r"#define PFDOA_(\w+)\s+(\(?-?\w+\)?)", header)}
    c_vals.update({m.group(1): int(m.group(2))
                   for m in re.finditer(r"PFDOA_(ERR_\w+) = (-\d+)", header)})
    mpy = (ROOT / "firmware/micropython/pfdoa_defs.py").read_text()
    m_vals = {m.group(1): int(m.group(2)) for m in re.finditer(r"^(\w+) = const\((-?\d+)\)", mpy, re.M)}
    # The anchors' files hold the current version; only the gateway's has version 1 (V1_*).
    py_vals = {k: v for k, v in vars(defs).items() if k.isupper() and isinstance(v, int)
               and not k.startswith(("V1_DEFS", "MSG_V1_", "CAN_V1_"))}
    assert c_vals == py_vals == m_vals
    assert py_vals["ERR_CAPACITY"] == py_vals["ERR_ARG"] - 1  # the numbers by hand: test_protocol_hand.py


def test_struct_formats_are_the_same_in_python_and_micropython_and_fit_the_layouts():
    import struct

    from pfdoa.protocol import defs

    mpy = (ROOT / "firmware/micropython/pfdoa_defs.py").read_text()
    m_fmts = dict(re.findall(r"^(\w+_FMT) = '([<\w]+)'", mpy, re.M))
    py_fmts = {k: v for k, v in vars(defs).items() if k.endswith("_FMT")}
    assert m_fmts == {k: v for k, v in py_fmts.items() if "V1_" not in k}
    assert len(py_fmts) == len(defs.MESSAGES) + len(defs.CAN_TYPES) + 2
    for name, spec in defs.MESSAGES.items():
        assert struct.calcsize(py_fmts[f"MSG_{name}_FMT"]) == spec[2] and spec[7] == py_fmts[f"MSG_{name}_FMT"]
    for name, (_t, dlc, _f, _v) in defs.CAN_TYPES.items():
        assert struct.calcsize(py_fmts[f"CAN_{name}_FMT"]) == dlc
    assert struct.calcsize(defs.FILTER_ENTRY_FMT) == defs.FILTER_ENTRY_LEN
    assert len(defs.FILTER_TABLE_DEFAULT) == defs.FILTER_TABLE_LEN
    assert f"FILTER_TABLE_DEFAULT = {defs.FILTER_TABLE_DEFAULT!r}" in mpy
    assert struct.unpack(defs.CONFIG_FMT, defs.CONFIG_DEFAULT) == (
        defs.DEFAULT_OFFSET_Q8, defs.DEFAULT_ALPHA_Q8, defs.DEFAULT_SPIKE_DB, defs.DEFAULT_REPORT_MODE,
        defs.DEFAULT_DECIMATION)
    assert f"CONFIG_DEFAULT = {defs.CONFIG_DEFAULT!r}" in mpy


def test_decode_errors_are_one_enum_with_the_c_codes():
    from pfdoa.protocol import defs

    header = (ROOT / "firmware/core/include/pfdoa_defs.h").read_text()
    c_codes = dict(re.findall(r"PFDOA_ERR_(\w+) = (-\d+)", header))
    for e in defs.DecodeError:
        assert e == e.value and str(e) == e.value and e in defs.ERRORS
        assert int(c_codes[e.name]) == e.code == getattr(defs, f"ERR_{e.name}")
    # the local errors follow the wire errors in the same domain
    assert sorted(int(v) for v in c_codes.values()) == list(range(-len(c_codes), 0))
