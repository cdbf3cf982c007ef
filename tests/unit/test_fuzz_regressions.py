"""Replay every committed fuzz input through its atheris harness (fuzz/py/harnesses.py).

fuzz/regressions/<target>/ holds the inputs that once crashed a target (named after the bug
they found); fuzz/corpus/<target>/ the seeds. Each must now pass the harness's checks:
no exception other than the documented InputError/ConfigError, and every invariant of
docs/security.md. The C targets' inputs are replayed by firmware/Makefile (test-c).
"""

import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "fuzz" / "py"))

import harnesses  # noqa: E402

CASES = sorted(
    (kind, p.parent.name, p)
    for kind in ("regressions", "corpus")
    for p in (ROOT / "fuzz" / kind).glob("*/*")
    if p.is_file() and p.parent.name in harnesses.TARGETS
)


def test_every_python_target_has_seeds():
    have = {t for k, t, _ in CASES if k == "corpus"}
    assert have == set(harnesses.TARGETS)


@pytest.mark.parametrize("kind,target,path", CASES, ids=[f"{k}/{t}/{p.name}" for k, t, p in CASES])
def test_replay(kind, target, path):
    harnesses.TARGETS[target](path.read_bytes())


def test_evicted_set_is_consistent():
    # fuzz/regressions/reassembler/evicted-set-gets-the-new-reading, reduced: with
    # max_open_sets sets open, a report for a sequence older than all of them opened a
    # set that was evicted at once, and the report was then written into the set already
    # emitted (rssi had the anchor, missing listed it too).
    from pfdoa.gateway.reassembly import Reading, SeqReassembler

    r = SeqReassembler((0, 1), max_open_sets=4, set_timeout_s=100.0)
    out = r.push(Reading(0, -50.0, 0.0, seq=0)) + r.push(Reading(1, -50.0, 0.0, seq=0))
    for s in (2, 3, 4, 5):
        out += r.push(Reading(0, -50.0, 0.0, seq=s))
    out += r.push(Reading(1, -51.0, 0.0, seq=1))
    assert r.open_sets <= 4
    for s in out:
        assert set(s.missing) == {0, 1} - set(s.rssi), s
    (evicted,) = [s for s in out if s.seq == 1]
    assert evicted.rssi == {1: -51.0} and evicted.missing == (0,)


def test_trace_integer_beyond_int64_is_an_input_error(tmp_path):
    from pfdoa.errors import InputError
    from pfdoa.trace import read_trace

    for col in ("anchor", "seq"):
        p = tmp_path / f"{col}.csv"
        vals = {"anchor": "1", "seq": "0"}
        vals[col] = "9" * 30
        p.write_text(f"t,anchor,rssi_dbm,seq\n0.0,{vals['anchor']},-60,{vals['seq']}\n")
        with pytest.raises(InputError, match=col):
            read_trace(p)


def test_site_integer_beyond_float_is_a_config_error(tmp_path):
    from pfdoa.errors import ConfigError
    from pfdoa.site import load_site

    p = tmp_path / "site.toml"
    p.write_text("[radio]\nrssi_at_1m_dbm = -59\npath_loss_exponent = 2\n"
                 "[[anchors]]\nid = 1\nx = 0\ny = 0\n[[anchors]]\nid = 2\nx = 1" + "0" * 400 +
                 "\ny = 0\n[[anchors]]\nid = 3\nx = 0\ny = 6\n")
    with pytest.raises(ConfigError, match="anchors"):
        load_site(p)


def test_capture_timestamp_beyond_float_is_a_bad_line():
    # fuzz/regressions/capture/timestamp-beyond-float-is-infinite: a 400-digit time parsed
    # to inf, and replay timers that follow the recorded times would then stay at inf
    # (every set timed out, every anchor stale) for the rest of the file.
    from pfdoa.gateway.inputs.capture import CaptureReader

    r = CaptureReader("unused.cap")
    assert r.parse_line("(" + "9" * 400 + ".0) ttyUSB0 S 0102") is None
    assert r.bad_lines == 1
    assert r.parse_line("(12.5) ttyUSB0 S 0102").t == 12.5


def test_committed_seeds_are_what_make_corpus_writes():
    # The seeds are built with the protocol code; stale ones (an older protocol version)
    # stop at the parsers' front doors and no longer seed the fuzzers past them.
    sys.path.insert(0, str(ROOT / "fuzz"))
    import make_corpus

    stale = [f"{t}/{n}" for t, n, data in make_corpus.seeds()
             if not (ROOT / "fuzz" / "corpus" / t / n).is_file() or (ROOT / "fuzz" / "corpus" / t / n).read_bytes() != data]
    assert not stale, f"re-run fuzz/make_corpus.py: {stale}"
