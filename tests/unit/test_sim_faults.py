import numpy as np
import pytest

from pfdoa.errors import InputError
from pfdoasim.backends.base import classify_uart_frames
from pfdoasim.backends.py_mean import MeanAnchor
from pfdoasim.faults import FaultConfig, FaultInjector, Frame, parse_faults


def test_parse_faults_spec():
    f = parse_faults("loss=0.02, dup=0.01,reorder=0.03,ber=1e-5,drift_ppm=100,silence=2@10+5,silence=3@1+2,portdrop=20+2,reboot=1")
    assert (f.loss, f.dup, f.reorder, f.ber, f.drift_ppm, f.reboot) == (0.02, 0.01, 0.03, 1e-5, 100.0, True)
    assert [(s.anchor, s.start_s, s.duration_s) for s in f.silence] == [(2, 10.0, 5.0), (3, 1.0, 2.0)]
    assert [(d.start_s, d.duration_s) for d in f.portdrop] == [(20.0, 2.0)]
    assert parse_faults("") == FaultConfig()
    for bad in ("loss=2", "loss=x", "warp=1", "silence=2", "silence=a@1+2", "portdrop=5", "portdrop=5+0", "loss"):
        with pytest.raises(InputError):
            parse_faults(bad)


def frames(n, anchor=1):
    a = MeanAnchor(anchor, can=False)
    out = []
    for k in range(n):
        a.radio(k, -60 - k % 5, 37, 0, 1, 1000 + 100 * k)
        out += [Frame(anchor, d, rep) for d, rep in classify_uart_frames(a.take_uart())]
    return out


def test_counts_add_up_and_match_what_reaches_the_wire():
    inj = FaultInjector(parse_faults("loss=0.1,dup=0.05,reorder=0.05"), np.random.default_rng(3))
    wire = []
    src = frames(2000)
    for f in src:
        wire += inj.apply(f)
    wire += inj.flush()
    c = inj.counts.total()
    assert c.frames == c.reports == 2000
    assert c.sent == len(wire) == c.frames - c.dropped + c.duplicated
    assert 150 < c.dropped < 250 and 60 < c.duplicated < 140 and 60 < c.reordered < 140
    # Reordering moves frames, it neither adds nor removes any.
    seqs = [_decode(f.data).seq for f in wire]
    assert len(set(seqs)) == c.frames - c.dropped
    assert sum(1 for i in range(1, len(seqs)) if seqs[i] < seqs[i - 1]) == c.reordered


def _decode(frame: bytes):
    from pfdoa.protocol import decode_frame

    return decode_frame(frame[:-1]).message


def test_bit_errors_flip_the_counted_bits_only():
    inj = FaultInjector(FaultConfig(ber=2e-3), np.random.default_rng(4))
    src = frames(3000)
    flipped = 0
    for f in src:
        (out,) = inj.apply(f)
        flipped += sum(bin(a ^ b).count("1") for a, b in zip(f.data, out.data))
    c = inj.counts.total()
    assert c.bit_flips == flipped > 0
    assert 0 < c.corrupted <= flipped
    nbits = sum(8 * len(f.data) for f in src)
    assert flipped / nbits == pytest.approx(2e-3, rel=0.2)


def test_can_bit_errors_are_retransmitted_not_corrupted():
    inj = FaultInjector(FaultConfig(ber=1e-2), np.random.default_rng(4), can=True)
    f = Frame(1, bytes(8), True, 0x101)
    outs = [inj.apply(f) for _ in range(500)]
    assert all(o == [f] for o in outs)
    assert inj.counts.total().retransmits > 100 and inj.counts.total().corrupted == 0


def test_silence_and_port_windows():
    f = parse_faults("silence=2@10+5,portdrop=20+2")
    inj = FaultInjector(f, np.random.default_rng(0))
    assert inj.silenced(2, 10.0) and inj.silenced(2, 14.9) and not inj.silenced(2, 15.0)
    assert not inj.silenced(1, 12.0)
    assert inj.port_down(21.0) and not inj.port_down(19.9) and not inj.port_down(22.0)
