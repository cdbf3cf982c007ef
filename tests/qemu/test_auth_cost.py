"""What the authenticated beacon (protocol/SPEC.md 9) costs on the Cortex-M images: the
instruction counts firmware/README.md states are what firmware/bench/auth_bench.c measures
under QEMU (-icount shift=0: virtual time is instructions, so the counts do not depend on
the machine's speed), and they say what the design claims: one HMAC per advertisement on
the beacon, one per reception at the anchor (the period's identifier cached), a replay
rejected only after its tag is checked."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from bench import firmware

pytestmark = pytest.mark.qemu

REPO = Path(__file__).resolve().parents[2]
KEYS = ("beacon_advertisement", "period_identifiers", "anchor_reception", "anchor_replay_rejected",
        "static_beacon_reception")


@pytest.fixture(scope="module")
def counts() -> dict:
    return firmware.auth_instructions()


def test_readme_table_is_the_measurement(counts):
    doc = (REPO / "firmware" / "README.md").read_text()
    for cpu, label in (("cortex-m4", "Cortex-M4"), ("cortex-m0plus", "Cortex-M0+")):
        row = re.search(rf"^\| {re.escape(label)} \|(.*)\|$", doc, re.M)
        assert row is not None, label
        cells = [int(c.strip().replace(",", "")) for c in row.group(1).split("|")]
        assert cells == [counts[cpu][k] for k in KEYS], (cpu, cells, counts[cpu])


def test_the_costs_are_those_of_the_design(counts):
    for cpu, c in counts.items():
        # SysTick calibration: the mps2 boards' 25 MHz against -icount's 1 GHz.
        assert c["instructions_per_kilotick"] == 40000, cpu
        # One HMAC (two SHA-256 compressions from the cached pads) is most of every cost.
        hmac = c["period_identifiers"]
        assert hmac < c["beacon_advertisement"] < 1.1 * hmac, cpu
        assert hmac < c["anchor_reception"] < 1.2 * hmac, cpu
        # A replay costs the tag check too (the window is checked after it), not more.
        assert hmac < c["anchor_replay_rejected"] < c["anchor_reception"], cpu
        # Our static beacon's reception needs no hash: an order of magnitude less.
        assert c["static_beacon_reception"] * 5 < c["anchor_reception"], cpu
