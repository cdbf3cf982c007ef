"""Rooms and floors (pfdoa.rooms): the site file's [[floors]] and [[rooms]] (checked at load,
written back by the one writer), the room and its probability of an estimate, the floor
filter, and the four output fields the localizer adds to every record."""

from __future__ import annotations

import io
import math
import textwrap

import numpy as np
import pytest

from pfdoa.cli import main
from pfdoa.errors import ConfigError
from pfdoa.output import FIELDS, Record, Writer
from pfdoa.rooms import Places, Plan, Room, inside, site_plan
from pfdoa.site import load_site, parse_site, site_to_toml

pytestmark = pytest.mark.unit

ANCHORS = "".join(f"\n[[anchors]]\nid = {i}\nx = {x}\ny = {y}\nz = {z}\n" for i, (x, y, z) in enumerate(
    [(0.0, 0.0, 2.5), (8.0, 0.0, 2.5), (8.0, 6.0, 2.5), (0.0, 6.0, 2.5),
     (0.0, 0.0, 5.5), (8.0, 0.0, 5.5), (4.0, 6.0, 5.5)]))
TWO_FLOORS = textwrap.dedent("""
    [radio]
    rssi_at_1m_dbm = -50.0
    path_loss_exponent = 2.2
    """) + ANCHORS + textwrap.dedent("""
    [[floors]]
    name = "ground"
    z = [0.0, 3.0]

    [[floors]]
    name = "first"
    z = [3.0, 6.0]

    [[rooms]]
    name = "kitchen"
    floor = "ground"
    polygon = [[0.0, 0.0], [4.0, 0.0], [4.0, 6.0], [0.0, 6.0]]

    [[rooms]]
    name = "lounge"
    floor = "ground"
    polygon = [[4.0, 0.0], [8.0, 0.0], [8.0, 6.0], [4.0, 6.0]]

    [[rooms]]
    name = "attic"
    floor = "first"
    polygon = [[0, 0], [8, 0], [8, 6], [0, 6]]
    """)


def write(tmp_path, text, name: str = "site.toml"):
    """The site file ``text`` in ``tmp_path``."""
    (tmp_path / name).write_text(text)
    return tmp_path / name


def test_floors_and_rooms_load_and_are_written_back_as_they_were(tmp_path):
    site = load_site(write(tmp_path, TWO_FLOORS))
    plan = site_plan(site)
    assert [f.name for f in plan.floors] == ["ground", "first"] and plan.anchor_floors == (0, 0, 0, 0, 1, 1, 1)
    assert [(r.name, r.floor) for r in plan.rooms] == [("kitchen", "ground"), ("lounge", "ground"), ("attic", "first")]
    text = site_to_toml(site)
    again = load_site(write(tmp_path, text))
    assert site_plan(again) == plan and site_to_toml(again) == text
    assert "[[floors]]" in text and "[[rooms]]" in text and 'floor = "first"' in text


@pytest.mark.parametrize("edit,key,words", [
    (lambda t: t.replace('z = [0.0, 3.0]', 'z = [3.0, 0.0]'), "floors[0].z", "zmin < zmax"),
    (lambda t: t.replace('z = [3.0, 6.0]', 'z = [2.0, 6.0]'), "floors[1].z", "overlaps floor 'ground'"),
    (lambda t: t.replace('z = [3.0, 6.0]', 'z = 3.0'), "floors[1].z", "[zmin, zmax]"),
    (lambda t: t.replace('name = "first"', 'name = "ground"', 1), "floors[1].name", "duplicate floor"),
    (lambda t: t.replace('name = "first"', 'name = ""', 1), "floors[1].name", "printable"),
    (lambda t: t.replace('z = [3.0, 6.0]', 'z = [3.0, 5.0]'), "anchors[4].z", "none of the [[floors]]"),
    (lambda t: t.replace("z = 5.5\n", "z = 2.5\n", 1), "floors[1]", "holds 2 anchors"),
    (lambda t: t.replace('floor = "first"', 'floor = "roof"'), "rooms[2].floor", "no [[floors]] entry"),
    (lambda t: t.replace('floor = "first"\n', ''), "rooms[2].floor", "missing key"),
    (lambda t: t.replace('name = "lounge"', 'name = "kitchen"'), "rooms[1].name", "duplicate room"),
    (lambda t: t.replace("[[4.0, 0.0], [8.0, 0.0], [8.0, 6.0], [4.0, 6.0]]", "[[4, 0], [8, 5], [8, 0], [4, 6]]"),
     "rooms[1].polygon", "not a simple polygon"),  # a bow tie
    (lambda t: t.replace("[[4.0, 0.0], [8.0, 0.0], [8.0, 6.0], [4.0, 6.0]]", "[[4, 0], [8, 0], [6, 0]]"),
     "rooms[1].polygon", "no area"),
    (lambda t: t.replace("[[4.0, 0.0], [8.0, 0.0], [8.0, 6.0], [4.0, 6.0]]", "[[4, 0], [8, 0], [8, 6], [8, 0]]"),
     "rooms[1].polygon", "listed twice"),
    (lambda t: t.replace("[[4.0, 0.0], [8.0, 0.0], [8.0, 6.0], [4.0, 6.0]]", "[[4, 0], [8, 0], [8, 6], [4, 6], "
                         "[4, 3], [6, 3], [4, 3.5]]"), "rooms[1].polygon", "not a simple polygon"),  # a spike
    (lambda t: t.replace("[[4.0, 0.0], [8.0, 0.0], [8.0, 6.0], [4.0, 6.0]]", "[[4, 0], [8, 0]]"),
     "rooms[1].polygon", "3 to 128"),
    (lambda t: t.replace("[[4.0, 0.0], [8.0, 0.0], [8.0, 6.0], [4.0, 6.0]]", "[[4, 0], [8, 0], [8, nan]]"),
     "rooms[1].polygon", "finite"),
    (lambda t: t.replace("[[4.0, 0.0], [8.0, 0.0], [8.0, 6.0], [4.0, 6.0]]", "[[4, 0], [8, 0], [8, 1e9]]"),
     "rooms[1].polygon", "within +-100000"),
    (lambda t: t.replace("[[4.0, 0.0], [8.0, 0.0], [8.0, 6.0], [4.0, 6.0]]", "[[4, 0], [8, 0], [8]]"),
     "rooms[1].polygon", "[x, y]"),
    (lambda t: t.replace('name = "attic"', 'name = "attic"\nwalls = 4'), "rooms[2].walls", "unknown key"),
    (lambda t: t + "\n[floors]\nname = 1\n", "<syntax>", ""),
    (lambda t: t.split("[[floors]]")[0] + "[[rooms]]\nname = \"a\"\nfloor = \"x\"\npolygon = [[0,0],[1,0],[1,1]]\n",
     "rooms[0].floor", "has no [[floors]]"),
    (lambda t: "rooms = 3\n" + t.split("[[floors]]")[0], "rooms", "array of tables"),
])
def test_a_bad_floor_or_room_is_one_error_naming_the_key(tmp_path, edit, key, words):
    with pytest.raises(ConfigError) as exc:
        load_site(write(tmp_path, edit(TWO_FLOORS)))
    assert exc.value.key == key and words in exc.value.problem, str(exc.value)


def test_the_command_line_says_it_in_one_line_and_exits_2(tmp_path, capsys):
    p = write(tmp_path, TWO_FLOORS.replace('floor = "first"', 'floor = "roof"'))
    trace = tmp_path / "t.csv"
    trace.write_text("t,anchor,rssi_dbm\n0.0,0,-60\n")
    assert main(["replay", str(trace), "--config", str(p)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "rooms[2].floor" in err[0] and "roof" in err[0]


def test_point_in_polygon_of_a_concave_room():
    ell = np.array([[0, 0], [4, 0], [4, 1], [1, 1], [1, 3], [0, 3]], dtype=float)  # an L
    pts = np.array([[0.5, 0.5], [3.5, 0.5], [0.5, 2.5], [2.0, 2.0], [3.5, 2.5], [-0.1, 0.5], [4.1, 0.5]])
    assert inside(pts, ell).tolist() == [True, True, True, False, False, False, False]
    grid = np.stack(np.meshgrid(np.linspace(-0.95, 4.95, 60), np.linspace(-0.95, 3.95, 50)), -1).reshape(-1, 2)
    expect = ((grid[:, 0] > 0) & (grid[:, 1] > 0) & (grid[:, 0] < 4) & (grid[:, 1] < 3)
              & ((grid[:, 1] < 1) | (grid[:, 0] < 1)))
    assert (inside(grid, ell) == expect).all()


def test_room_p_is_the_share_of_the_uncertainty_inside_the_room():
    plan = Plan((), (Room("west", None, ((0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0))),
                     Room("east", None, ((10.0, 0.0), (20.0, 0.0), (20.0, 10.0), (10.0, 10.0)))))
    pl = Places(plan, np.zeros(3))
    deep = pl.place(5.0, 5.0, (0.04, 0.0, 0.04), None, None)
    assert (deep.room, deep.floor, deep.floor_p) == ("west", None, None) and deep.room_p == pytest.approx(1.0)
    # On the wall between the two rooms, half the mass is on either side (+- the samples' 2 %).
    wall = pl.place(9.999, 5.0, (1.0, 0.0, 1.0), None, None)
    assert wall.room == "west" and wall.room_p == pytest.approx(0.5, abs=0.03)
    # One sigma inside: Phi(1) = 84 %; with sigma only (no cov) the same.
    one = pl.place(9.0, 5.0, (1.0, 0.3, 1.0), None, None)
    assert one.room_p == pytest.approx(0.8413, abs=0.03)
    assert pl.place(9.0, 5.0, None, None, None) == type(one)(None, None, "west", None)
    assert pl.place(25.0, 5.0, (1.0, 0.0, 1.0), None, None).room is None
    assert pl.place(math.nan, 5.0, (1.0, 0.0, 1.0), None, None).room is None


def test_the_floor_filter_follows_the_floor_whose_anchors_hear_best(tmp_path):
    site = load_site(write(tmp_path, TWO_FLOORS))
    pl = Places(site_plan(site), site.offsets)
    assert pl.multi_floor
    ground = np.array([-55, -60, -62, -58, -75, -78, -80], dtype=float)  # ground anchors louder
    first = np.array([-76, -79, -80, -77, -56, -59, -63], dtype=float)
    floors = []
    for k in range(40):
        rssi = ground if k < 20 else first
        rssi = rssi + (3.0 if k % 7 == 3 else 0.0) * np.r_[-1, -1, -1, -1, 1, 1, 1]  # a noisy set now and then
        f, p = pl.floor(0.2 * k, rssi)
        floors.append((f, p))
    names = [site_plan(site).floors[f].name for f, _ in floors]
    assert names[:20] == ["ground"] * 20 and names[22:] == ["first"] * 18  # switched within two sets
    assert all(p > 0.99 for _, p in floors[5:20]) and all(p > 0.99 for _, p in floors[25:])
    # The other floor's anchors count as not heard; offsets are removed before comparing floors.
    masked = pl.mask(first, 1)
    assert np.isnan(masked[:4]).all() and (masked[4:] == first[4:]).all()
    pl.reset()
    shifted = Places(site_plan(site), np.r_[0, 0, 0, 0, 30, 30, 30])  # first-floor radios read 30 dB hot
    assert shifted.floor(0.0, first)[0] == 0


def test_every_record_carries_room_and_floor_and_the_csv_appends_them(tmp_path):
    p = write(tmp_path, TWO_FLOORS)
    trace = tmp_path / "t.csv"
    rows = ["t,anchor,rssi_dbm,seq"]
    for k in range(30):  # a beacon at (2, 3) on the ground floor
        for a, r in enumerate([-62, -68, -68, -62, -80, -84, -82]):
            rows.append(f"{0.2 * k + 0.001 * a:.3f},{a},{r},{k}")
    trace.write_text("\n".join(rows) + "\n")
    out = tmp_path / "est.csv"
    assert main(["-q", "replay", str(trace), "--config", str(p), "--seed", "1", "--format", "csv",
                 "--out", str(out)]) == 0
    lines = out.read_text().splitlines()
    assert lines[0].split(",")[-4:] == ["room", "room_p", "floor", "floor_p"] == list(FIELDS[-4:])
    last = dict(zip(lines[0].split(","), lines[-1].split(",")))
    assert last["floor"] == "ground" and float(last["floor_p"]) > 0.99
    assert last["room"] == "kitchen" and 0.5 < float(last["room_p"]) <= 1.0
    assert set(last["anchors"].split(";")) <= {"0", "1", "2", "3"}  # the ground floor's anchors alone
    # A site without rooms or floors: the fields are there, empty.
    buf = io.StringIO()
    Writer(buf, "csv").write(Record(t=1.0, x=0.0, y=0.0))
    assert buf.getvalue().splitlines()[1].endswith(",,,,")


def test_a_site_with_rooms_only_has_no_floor_and_sees_every_anchor(tmp_path):
    text = TWO_FLOORS.split("[[floors]]")[0] + "[[rooms]]\nname = \"all\"\npolygon = [[0,0],[8,0],[8,6],[0,6]]\n"
    site = parse_site(__import__("pfdoa._toml", fromlist=["loads"]).loads(text), "x")
    pl = Places(site_plan(site), site.offsets)
    assert not pl.multi_floor and pl.floor(0.0, np.zeros(7)) == (None, None)
    rssi = np.arange(7.0)
    assert pl.mask(rssi, None) is rssi
    assert pl.place(4.0, 3.0, (0.1, 0.0, 0.1), None, None).room == "all"
