"""Floors and rooms in a two-floor house (pfdoasim.building): the simulator's beacon walks
both floors and takes the stair between them, every anchor hears it through 3-D distance and
the floor slab, and `pfdoa replay` (the gateway's localizer: floor filter, that floor's
anchors, estimator, room) names the floor and the room of every estimate. Fixed seeds; the
thresholds are the issue's (floor 98 % away from the stair, room 90 % more than 0.5 m from a
wall); what was measured is printed (pytest -s) and in docs/fleet.md."""

from __future__ import annotations

import json

import pytest

from pfdoa.rooms import site_plan
from pfdoasim.building import FLOORS, BuildingConfig, BuildingWalk, run_building, true_floor

pytestmark = pytest.mark.sil

SEEDS = (1, 2, 3)


@pytest.fixture(scope="module")
def scores(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("building")
    return {s: (run_building(BuildingConfig(seed=s), tmp), tmp / f"building-{s}") for s in SEEDS}


def test_floor_and_room_of_every_estimate_in_a_two_floor_house(scores):
    for seed, (sc, out) in scores.items():
        print(f"seed {seed}: floor {sc.floor_correct}/{sc.floor_scored} = {100 * sc.floor_rate:.1f} %, "
              f"room {sc.room_correct}/{sc.room_scored} = {100 * sc.room_rate:.1f} %, "
              f"mean error {sc.mean_error_m:.2f} m")
        assert sc.estimates >= 700  # 150 s at 5 sets a second
        assert sc.floor_scored >= 300 and sc.room_scored >= 300, sc
        assert sc.floor_rate >= 0.98, sc
        assert sc.room_rate >= 0.90, sc
        recs = [json.loads(ln) for ln in (out / "estimates.jsonl").read_text().splitlines()]
        walk = BuildingWalk(BuildingConfig(seed=seed))
        truth = walk.truth([r["t"] for r in recs])
        # The walk was on both floors for long, and so were the estimates.
        for name, _lo, _hi in FLOORS:
            assert sum(true_floor(z) == name for z in truth[:, 2]) > 150
            assert sum(r["floor"] == name for r in recs) > 150
        # Every estimate used its floor's anchors only, and said how sure it is.
        plan = site_plan(walk.site)
        floor_of = {a.id: plan.floors[f].name for a, f in zip(walk.site.anchors, plan.anchor_floors)}
        assert all({floor_of[a] for a in r["anchors"]} <= {r["floor"]} for r in recs)
        assert all(0.5 <= r["floor_p"] <= 1.0 for r in recs)
        in_room = [r for r in recs if r["room"] is not None]
        assert len(in_room) > 0.95 * len(recs)  # the rooms tile both floors
        assert all(0.0 <= r["room_p"] <= r["floor_p"] + 1e-9 for r in in_room)


def test_the_house_and_its_run_are_a_function_of_the_seed(tmp_path):
    a, b = BuildingWalk(BuildingConfig(seed=5, duration_s=40.0)), BuildingWalk(BuildingConfig(seed=5, duration_s=40.0))
    assert (a.readings() == b.readings()).all() and (a.readings() == a.readings()).all()
    other = BuildingWalk(BuildingConfig(seed=6, duration_s=40.0))
    assert other.readings().shape != a.readings().shape or (other.readings() != a.readings()).any()
    r = a.readings()
    # A slab costs its loss: the beacon on the ground floor is heard louder by the ground floor's anchors.
    ground = [a.id for a in a.site.anchors if a.z < FLOORS[0][2]]
    k = a.truth(r[:, 0])[:, 2] < FLOORS[0][2]
    mine = r[k & [int(x) in ground for x in r[:, 1]], 2].mean()
    theirs = r[k & [int(x) not in ground for x in r[:, 1]], 2].mean()
    assert mine - theirs > 10.0
