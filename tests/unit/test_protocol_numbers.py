"""No protocol number outside the generated files (issue 14).

protocol/messages.json is the one place the wire contract's numbers are written down;
protocol/gen.py turns it into firmware/core/include/pfdoa_defs.h, host/pfdoa/protocol/defs.py
and firmware/micropython/pfdoa_defs.py. Everything else must name the generated constants.
This test scans every tracked .py / .c / .h file (code only: comments are free to quote a
number) for what a hand-written copy of the contract looks like:

* ``redefined``: a generated constant's name given a literal value (``MAX_RAW = 64``,
  ``#define PFDOA_CRC_POLY 0x1021``), in any case, with or without the PFDOA_ prefix;
* ``hash``: the CRC-16 values the generator computes (each version's defs_hash, the
  default configuration's and filter table's hashes), decimal or hex;
* ``format``: a string literal equal to a generated struct format (payload layouts);
* ``can``: a shift by the CAN anchor bits (``<< 7``, ``>> 7``), a 0x7F / 0x7FF / 0x780
  mask, or a 3-digit hex CAN identifier (0x080..0x3FF, the can_type bits above an anchor id);
* ``anchor_id``: an anchor-id bound (126 / 127 compared with an anchor id, ``0..126``,
  ``% 127``);
* ``crc_extra``: a CRC_EXTRA value on a line about CRC_EXTRA;
* ``length``: MAX_RAW / MAX_BODY / MAX_ENCODED on a line about frame lengths or buffers;
* ``type``: a message type compared with a literal (``type == 5``), or 0x7D / 0x7E;
* ``flags``: flag bits tested or set with a literal (``flags & 0x20``);
* ``error``: an error code compared with or returned as a negative literal.

These detectors are deliberately specific (a general "no small integers" rule would flag
every loop); what they cannot see (a bare 65 used as MAX_ENCODED) is for review. The
exceptions are listed below, each with its reason; an exception that no longer matches
anything fails the test, so the list stays minimal.
"""

from __future__ import annotations

import io
import re
import subprocess
import tokenize
from pathlib import Path

import pytest

from pfdoa.protocol import defs

ROOT = Path(__file__).resolve().parents[2]

# The generated files, the generator and what it must not depend on.
GENERATED = {
    "firmware/core/include/pfdoa_defs.h",
    "host/pfdoa/protocol/defs.py",
    "firmware/micropython/pfdoa_defs.py",
}
WHOLE_FILE_EXCEPTIONS = {
    # The generator and the golden-vector writer: messages.json's numbers are their input,
    # and a vector's field values are data (e.g. flags=16 | 8), not code that decodes.
    "protocol/gen.py": "the generator",
    "protocol/gen_vectors.py": "writes the golden vectors",
    # gen.py loads crc.py by path to check messages.json before defs.py exists.
    "host/pfdoa/protocol/crc.py": "bootstrap of the generator (CRC_INIT, CRC_POLY)",
    # An independent re-derivation of SPEC.md by hand, to catch a generator that is
    # consistently wrong: it must not use the generated numbers.
    "tests/unit/test_protocol_hand.py": "independent hand check of the spec",
    # This file (the numbers it looks for are built from defs, but its docstring and
    # regexes spell some).
    "tests/unit/test_protocol_numbers.py": "the scan itself",
}
# (path, text on the line, detector): numbers in files this branch may not edit; the
# generated constant each should use exists (named in the comment).
LINE_EXCEPTIONS = [
    # fuzz/py/harnesses.py (the gateway's fuzz targets): defs.ANCHOR_BROADCAST, defs.ANCHOR_ID_MAX.
    ("fuzz/py/harnesses.py", "0 <= d.anchor_id <= 127", "anchor_id"),
    ("fuzz/py/harnesses.py", "all(0 <= a <= 126 for a in ids)", "anchor_id"),
    # Gateway / simulator transport tests (not ours): CAN ids by hand; should use
    # pfdoa.protocol.can.can_id_for(defs.CAN_*, anchor) and defs.CAN_ANCHOR_MASK.
    ("tests/io/test_transports.py", "arbitration_id=0x185", "can"),
    ("tests/io/test_transports.py", "arbitration_id=0x102", "can"),
    ("tests/io/test_transports.py", 'Chunk("can0", 1700000000.5, b"\\xaa" * 8, 0x102)', "can"),
    ("tests/io/test_transports.py", '("can0", 1700000000.5, b"\\xaa" * 8, 0x102)', "can"),
    ("tests/io/test_sim_transports.py", "{0x100 | a for a in (1, 2, 3, 4)}", "can"),
    ("tests/io/test_sim_transports.py", "m.arbitration_id & 0x7F", "can"),
    # Not a protocol number: an arbitrary identifier for the SLCAN text format's test.
    ("tests/io/test_sim_transports.py", "slcan_line(0x123,", "can"),
    # tests/qemu/test_qemu_port.py (the QEMU port's): defs.FLAG_RESET.
    ("tests/qemu/test_qemu_port.py", "rep.flags & 8", "flags"),
]

CODE_GLOBS = ("*.py", "*.c", "*.h")


def _tracked() -> list[str]:
    out = subprocess.run(["git", "ls-files", "--", *CODE_GLOBS], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.split()
    # Files the scan has not seen committed yet still count (a new module before its commit).
    untracked = subprocess.run(["git", "ls-files", "--others", "--exclude-standard", "--", *CODE_GLOBS], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.split()
    return sorted(set(out) | set(untracked))


# ------------------------------------------------------------------ code without comments

def _python_code(text: str) -> list[str]:
    """The lines of a Python file with comments and docstrings blanked (strings kept)."""
    lines = text.splitlines()
    out = [list(line) for line in lines]
    try:
        toks = list(tokenize.generate_tokens(io.StringIO(text).readline))
    except (tokenize.TokenError, SyntaxError):
        return lines
    prev = tokenize.NEWLINE
    for tok in toks:
        kind = tok.type
        blank = kind == tokenize.COMMENT or (
            kind == tokenize.STRING and prev in (tokenize.NEWLINE, tokenize.NL, tokenize.INDENT, tokenize.DEDENT))
        if blank:
            (r0, c0), (r1, c1) = tok.start, tok.end
            for r in range(r0, r1 + 1):
                a = c0 if r == r0 else 0
                b = c1 if r == r1 else len(out[r - 1])
                out[r - 1][a:b] = " " * (b - a)
        if kind not in (tokenize.COMMENT, tokenize.NL):
            prev = kind
    return ["".join(x) for x in out]


_C_TOKEN = re.compile(r'//[^\n]*|/\*.*?\*/|"(?:\\.|[^"\\\n])*"|\'(?:\\.|[^\'\\\n])*\'', re.S)


def _c_code(text: str) -> list[str]:
    """The lines of a C file with comments blanked (strings kept, newlines preserved)."""
    def keep(m: re.Match) -> str:
        s = m.group(0)
        if s.startswith("/"):
            return re.sub(r"[^\n]", " ", s)
        return s
    return _C_TOKEN.sub(keep, text).splitlines()


# ------------------------------------------------------------------ detectors

def _generated_names() -> dict[str, int]:
    return {k: v for k, v in vars(defs).items() if k.isupper() and isinstance(v, int) and not isinstance(v, bool)}


def _int_re(values) -> str:
    alts = set()
    for v in values:
        alts.add(str(v))
        alts.add(f"0x{v:x}")
        alts.add(f"0x{v:X}")
        alts.add(f"0x{v:04x}")
        alts.add(f"0x{v:04X}")
    return r"(?<![\w.])(?:" + "|".join(sorted(map(re.escape, alts), key=len, reverse=True)) + r")[uUlL]*(?![\w.])"


class _Redefined:
    """A generated constant's name (any case, optional PFDOA_ / _ prefix) given an integer."""

    def __init__(self, names, int_value: str) -> None:
        self._names = {n.upper() for n in names}
        self._rx = re.compile(rf"^\s*(?:#\s*define\s+(\w+)\s+{int_value}|(\w+)\s*(?::\s*\w+\s*)?=\s*{int_value})")

    def search(self, line: str) -> bool:
        m = self._rx.search(line)
        if not m:
            return False
        name = (m.group(1) or m.group(2)).upper()
        for prefix in ("PFDOA_", "_"):
            name = name[len(prefix):] if name.startswith(prefix) else name
        return name in self._names


def _detectors() -> list:
    names = _generated_names()
    hashes = {defs.DEFS_HASH, defs.V1_DEFS_HASH, defs.CONFIG_DEFAULT_HASH, defs.FILTER_TABLE_DEFAULT_HASH}
    fmts = {v for k, v in vars(defs).items() if k.endswith("_FMT") and isinstance(v, str)}
    fmt_alt = "|".join(sorted(map(re.escape, fmts), key=len, reverse=True))
    num = r"(?:0[xX][0-9a-fA-F]+|\d+)[uUlL]*"
    int_value = r"[-(]*(?:0[xX][0-9a-fA-F]+|\d+(?![\d.eE]))"  # an integer, not a float
    errors = "|".join(str(e) for e in range(1, -defs.ERR_CAPACITY + 1))
    extras = {m[3] for m in defs.MESSAGES.values() if m[3] >= 10}
    lengths = {defs.MAX_RAW, defs.MAX_BODY, defs.MAX_ENCODED}
    errors_but_1 = "|".join(str(e) for e in range(2, -defs.ERR_CAPACITY + 1))
    return [
        ("redefined", _Redefined(names, int_value)),
        ("hash", re.compile(_int_re(hashes))),
        ("format", re.compile(rf"""(?<![\w])[bBrR]?(['"])(?:{fmt_alt})\1""")),
        # CAN: the anchor-id shift, the anchor-id / trailer mask, the type mask, and a
        # 3-digit hex identifier on a line about CAN ids.
        ("can", re.compile(r"(?:<<|>>)\s*7(?![\w.])|&\s*0[xX]7[fF][uU]?(?![\w.])|(?<![\w.])0[xX]780[uU]?(?![\w.])"
                           r"|^(?i:(?=.*(?:can|_id\b|\bid\b|arbitration)).*(?<![\w.])0[xX][0-3][0-9a-fA-F]{2}[uU]?(?![\w.]))")),
        # An anchor-id bound: 126 / 127 compared against, in a "0..126" range, or modulo 127.
        ("anchor_id", re.compile(r"^(?i:(?=.*(?:anchor|\baid\b|\bids?\b))).*(?:(?:<=?|>=?)\s*12[67](?![\w.])"
                                 r"|(?<![\w.])12[67]\s*(?:<=?|>=?))"
                                 r"|(?<![\w.])0\s*\.\.\s*12[67](?![\w.])|%\s*127(?![\w.])")),
        # A CRC_EXTRA value on a line about CRC_EXTRA.
        ("crc_extra", re.compile(r"^(?i:(?=.*extra)).*" + _int_re(extras))),
        # MAX_RAW / MAX_BODY / MAX_ENCODED on a line about lengths or buffers.
        ("length", re.compile(r"^(?i:(?=.*(?:raw|encoded|body|frame(?!s)))(?=.*(?:len|max|size|buf|cap)))"
                              r".*(?<![\w.])(?:" + "|".join(map(str, lengths)) + r")(?![\w.])")),
        ("type", re.compile(rf"\b(?:msg_|frame_|can_)?type\s*(?:==|!=)\s*{num}(?![\w.])"
                            r"|(?<![\w.])0[xX]7[dDeE][uU]?(?![\w.])")),
        ("flags", re.compile(rf"\bflags\w*\s*(?:&|\|)=?\s*{num}(?![\w.])")),
        # An error code as a literal: compared with a result, or returned by C (a bare
        # `return -1;` is the usual "failed" of a HAL callback, not a protocol error).
        ("error", re.compile(rf"\b(?:rc|ret|result|err\w*|error\w*)\s*(?:==|!=)\s*\(?-\s*(?:{errors})(?![\w.])"
                             rf"|\breturn\s*\(?-\s*(?:{errors_but_1})\)?\s*;")),
    ]


def scan(paths: list[str] | None = None, read=lambda p: (ROOT / p).read_text(errors="replace")):
    """Every (path, line number, detector, line) hit in paths (default: the tracked code)."""
    hits = []
    dets = _detectors()
    for path in (_tracked() if paths is None else paths):
        if path in GENERATED or path in WHOLE_FILE_EXCEPTIONS or "/build/" in path or path.startswith(".venv"):
            continue
        try:
            text = read(path)
        except FileNotFoundError:
            continue  # deleted in the work tree
        lines = _python_code(text) if path.endswith(".py") else _c_code(text)
        raw = text.splitlines()
        for i, line in enumerate(lines):
            for name, rx in dets:
                if rx.search(line):
                    hits.append((path, i + 1, name, raw[i].strip() if i < len(raw) else line.strip()))
    return hits


def _excepted(hit) -> bool:
    path, _, det, line = hit
    return any(path == p and text in line and det == d for p, text, d in LINE_EXCEPTIONS)


# ------------------------------------------------------------------ tests

def test_no_protocol_number_outside_the_generated_files():
    hits = [h for h in scan() if not _excepted(h)]
    assert not hits, "hand-written protocol numbers (use the generated constants):\n" + "\n".join(
        f"  {p}:{n}: [{d}] {line}" for p, n, d, line in hits)


def test_every_exception_is_still_needed():
    hits = scan()
    stale = [e for e in LINE_EXCEPTIONS if not any(h[0] == e[0] and e[1] in h[3] and h[2] == e[2] for h in hits)]
    assert not stale, f"exceptions that match nothing any more (remove them): {stale}"
    for path in WHOLE_FILE_EXCEPTIONS:
        assert (ROOT / path).exists(), path
    for path in GENERATED:
        assert (ROOT / path).exists(), path


PLANTED = [
    ("host/pfdoa/x.py", "MAX_ENCODED = 65\n", "redefined"),
    ("host/pfdoa/x.py", "class A:\n    crc_poly: int = 0x1021\n", "redefined"),
    ("firmware/core/src/x.c", "#define PFDOA_MAX_RAW 64\n", "redefined"),
    ("host/pfdoa/x.py", f"if status.defs_hash != {defs.DEFS_HASH}:\n    pass\n", "hash"),
    ("firmware/core/src/x.c", f"    if (h == 0x{defs.V1_DEFS_HASH:04X}u) {{\n", "hash"),
    ("host/pfdoa/x.py", f"fields = struct.unpack('{defs.MSG_RSSI_REPORT_FMT}', payload)\n", "format"),
    ("sim/x.py", "if (can_id >> 7) == 0x2:\n    pass\n", "can"),
    ("firmware/core/src/x.c", "    const uint16_t id = (uint16_t)((2u << 7) | a);\n", "can"),
    ("firmware/tests/x.c", "    assert_int_equal(f.can_id, 0x285);\n", "can"),
    ("host/pfdoa/x.py", "anchor = can_id & 0x7F\n", "can"),
    ("host/pfdoa/x.py", "if msg_type == 5:\n    pass\n", "type"),
    ("firmware/core/src/x.c", "    if (f->type != 0x7E) {\n", "type"),
    ("host/pfdoa/x.py", "no_seq = bool(r.flags & 0x20)\n", "flags"),
    ("firmware/core/src/x.c", "    return -3;\n", "error"),
    ("host/pfdoa/x.py", "if rc == -7:\n    pass\n", "error"),
]


@pytest.mark.parametrize("path,text,detector", PLANTED)
def test_a_planted_number_is_found(path, text, detector):
    hits = scan([path], read=lambda p: text)
    assert detector in {h[2] for h in hits}, hits


@pytest.mark.parametrize("path,text", [
    ("host/pfdoa/x.py", "# MAX_ENCODED = 65 bytes between delimiters\nx = defs.MAX_ENCODED\n"),
    ("host/pfdoa/x.py", 'def f():\n    """flags & 0x20 is NO_SEQ."""\n    return 1\n'),
    ("firmware/core/src/x.c", "/* (can_type << 7) | anchor_id */\nx = PFDOA_CAN_ANCHOR_BITS;\n"),
    ("firmware/core/src/x.c", "    x ^= x << 13;\n    x ^= x >> 17;\n    return -1 - k;\n"),
    ("host/pfdoa/x.py", "max_raw = defs.MAX_RAW\nn = len(frame) - 1\n"),
])
def test_comments_and_named_constants_are_not_flagged(path, text):
    assert scan([path], read=lambda p: text) == []
