"""Corruption detection (tools/corruption.py, smaller) and garbage-only streams.

The full measurement (10^6 frames, every channel model) is in docs/reliability.md. Here:
every 1- and 2-bit error of every golden frame is rejected (exhaustive, SPEC 2.4); no
single, double or triple bit flip and no burst of <= 16 bits on the wire is accepted with
wrong content in random version-2 frames; the CRC alone lets about 2^-16 through the real
decoder; garbage alone never yields a frame.
"""

import math
import random
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools"))

import corruption  # noqa: E402

from pfdoa.protocol import StreamDecoder, defs  # noqa: E402
from pfdoa.protocol.uart import ANCHOR_TO_HOST, Decoded, decode_frame  # noqa: E402


def _patterns(frames, k):
    return sum(math.comb(8 * len(f), k) for f in frames)


def test_every_1_and_2_bit_error_of_every_golden_frame_is_rejected():
    # The decoder with every type and both versions accepts at least what any receiver
    # (gateway or anchor) accepts; none of 1- and 2-bit errors may get through it.
    frames = corruption.golden_frames(defs.PROTO_VERSION)
    assert len(frames) >= 20
    for f in frames:
        assert isinstance(decode_frame(f[:-1]), Decoded)  # the undamaged frame is good
    r = corruption.exhaustive(frames, max_flips=2)
    assert r["by_flips"][1] == {"frames": len(frames), "patterns": _patterns(frames, 1), "accepted": 0}
    assert r["by_flips"][2] == {"frames": len(frames), "patterns": _patterns(frames, 2), "accepted": 0}
    assert r["accepted"] == []


def test_version_1_frames_guarantee_less_as_spec_8_2_says():
    # Version 1 puts its CRC over the decoded bytes: a flipped COBS code byte can be
    # accepted (issue 14's frame). Every accepted 1- or 2-bit error involves a code byte.
    frames = corruption.golden_frames(defs.V1_PROTO_VERSION)
    r = corruption.exhaustive(frames, max_flips=2)
    assert r["by_flips"][1]["patterns"] == _patterns(frames, 1)
    issue_14 = bytes.fromhex("0401023e0311030b2116cd0fc4190618d912041f105c00")
    assert {"frame": issue_14.hex(), "bits": (7,), "code_byte": True} in r["accepted"]
    assert all(a["code_byte"] for a in r["accepted"])
    # The figure docs/security.md (G5) states.
    one = r["by_flips"][1]
    doc = (Path(__file__).resolve().parents[2] / "docs" / "security.md").read_text()
    assert f"{one['accepted']} of the {one['patterns']} single-bit errors of the golden version-1 frames" in doc
    # The anchor's version-2-only receiver refuses them all.
    r2 = corruption.exhaustive(frames, max_flips=1, versions=(defs.PROTO_VERSION,))
    assert r2["by_flips"][1]["accepted"] == 0


def test_guaranteed_detection_on_the_wire():
    res = corruption.run(20_000, seed=11, models=("flip1", "flip2", "flip3", "burst16"))
    for model, r in res.items():
        assert r["frames"] == 5000
        assert r["wrong"] == 0, (model, r["examples"])
        assert r["rejected"] + r["intact"] == r["frames"]


def test_corruption_models_damage_what_they_say():
    rng = np.random.default_rng(3)
    wire = bytes(range(1, 20))
    for _ in range(200):
        b = corruption.corrupt(wire, "flip2", rng)
        assert sum(bin(x ^ y).count("1") for x, y in zip(wire, b)) == 2
        b = corruption.corrupt(wire, "burst16", rng)
        diff = int.from_bytes(wire, "big") ^ int.from_bytes(b, "big")
        assert diff and diff.bit_length() - (diff & -diff).bit_length() + 1 <= 16
        assert len(corruption.corrupt(wire, "truncate", rng)) < len(wire)
        assert len(wire) < len(corruption.corrupt(wire, "insert", rng)) <= len(wire) + 8


def test_crc_only_rate_is_about_two_to_the_minus_16():
    r = corruption.run_crc_only(100_000, seed=5)
    # Every damaged frame got past COBS, version, type and length and was judged by the
    # CRC alone; expected 100000 * 2^-16 = 1.5 accepted (P(> 8) ~ 1e-4), while an 8-bit
    # check would pass about 390.
    assert r["other"] == 0
    assert r["bad_crc"] + r["passed"] == r["frames"]
    assert r["passed"] <= 8


def test_garbage_only_streams_yield_nothing():
    rng = random.Random(77)
    for _ in range(30):
        dec = StreamDecoder(types=ANCHOR_TO_HOST)
        out = []
        for _ in range(50):
            chunk = bytes(0 if rng.random() < 1 / 12 else rng.randrange(1, 256) for _ in range(rng.randrange(1, 400)))
            out += dec.feed(chunk)
        assert out == []
        c = dec.counters
        assert c["frames_ok"] == 0
        assert sum(c[e] for e in defs.ERRORS) > 0
        assert dec.pending <= defs.MAX_ENCODED
