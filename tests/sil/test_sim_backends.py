"""The simulator's two real anchor implementations emit the same bytes: the C core (ctypes)
and the MicroPython anchor (run by CPython), fed the same seeded scenario."""

from dataclasses import replace

import pytest

from pfdoasim.backends import anchor_factory
from pfdoasim.faults import parse_faults
from pfdoasim.runner import Simulation
from pfdoasim.scenario import build
from pfdoasim.transports import Transport


class Capture(Transport):
    def __init__(self, can: bool) -> None:
        self.is_can = can
        self.frames = []

    def send(self, frames):
        self.frames += [(f.anchor, f.can_id, f.data) for f in frames]
        return 0


@pytest.mark.parametrize("can", [False, True])
@pytest.mark.parametrize("scenario", ["demo", "paper-inside"])
def test_c_core_and_micropython_anchor_agree(scenario, can):
    sc = build(scenario, seed=11, duration_s=6.0)
    # Multipath bursts exercise the spike filter; drift and a reboot the tick handling.
    sc = replace(sc, channel=replace(sc.channel, multipath_prob=0.2, multipath_db=15.0),
                 faults=parse_faults("drift_ppm=300,silence=2@2+1,reboot=1"))
    out = {}
    for backend in ("c", "mpy"):
        tr = Capture(can)
        summary = Simulation(sc, tr, anchor_factory(backend), speed=0).run()
        out[backend] = (tr.frames, summary["faults"]["total"]["reports"])
    assert out["c"][1] > 4 * 50
    assert out["c"] == out["mpy"]
