"""Rooms and floors: where an estimate is, in the building's own words.

A site file may name its floors and rooms (both optional)::

    [[floors]]
    name = "ground"
    z = [0.0, 3.0]          # m: [zmin, zmax); an anchor whose z is in it is on this floor
    target_z = 1.0          # m, optional: the beacon's height on this floor (default: [site]
                            # target_z + zmin - the lowest floor's zmin)

    [[rooms]]
    name = "kitchen"
    floor = "ground"        # a [[floors]] name: required when there are floors, absent otherwise
    polygon = [[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]]   # m, site frame, in order around it

:func:`parse_plan` checks them when the site is loaded (``pfdoa.site.parse_site``): one
:class:`~pfdoa.errors.ConfigError` naming the key. Floor names are unique, their z ranges
do not overlap, and with floors every anchor's z lies on one of them and a floor that holds
anchors holds at least :data:`MIN_FLOOR_ANCHORS` (its estimates use them alone, below).
Room names are unique; a polygon has 3 to :data:`MAX_VERTICES` vertices within
:data:`MAX_COORD_M`, a non-zero area and no edge that crosses or touches another (a simple
polygon). Rooms on one floor should not overlap: where they do, the first one listed wins.
The tables stay in ``Site.sections`` as written, so ``site_to_toml`` writes them back.

Every estimate then gets four output fields (:mod:`pfdoa.output`), computed by a
:class:`Places` per beacon (the gateway's and replay's localizer,
:class:`pfdoa.gateway.localizer.Localizer`):

* ``floor``, ``floor_p``: with floors, the floor the beacon is on and its probability. A
  forward filter over the floors that hold anchors: each set's evidence for floor f is the
  mean of its :data:`FLOOR_TOP` strongest readings from f's anchors (offsets removed; a floor
  that heard nothing scores :data:`SILENT_DBM`), as a log-likelihood of that over
  :data:`FLOOR_SCALE_DB`; between two sets the beacon changes floor with probability
  1 - exp(-dt / :data:`FLOOR_DWELL_S`). A slab between an anchor and the beacon costs
  10-20 dB, more than any spread of distances on one floor, so the floor whose anchors hear
  it best is the floor it is on. With anchors on several floors the estimator is then
  stepped with that floor's anchors only (the others count as not heard for that set): a
  model of one plane, or of heights without slabs, would take the readings through a
  floor for distance. Their heights are above the beacon on that floor (:func:`floor_site`):
  one ``[site] target_z`` would put an upper floor's anchors a floor too high. Without
  floors: None.
* ``room``, ``room_p``: the room (on the estimated floor) whose polygon holds the estimate's
  (x, y), and the probability that the beacon is in it: the share of the position's
  uncertainty (a Gaussian of the estimate's ``cov``, else of ``sigma``) inside the polygon,
  times ``floor_p`` when there are floors. Outside every room, or without rooms: None
  (``room_p`` None also for a method without uncertainty).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from pfdoa import schema
from pfdoa.errors import ConfigError

MAX_FLOORS = 32
MAX_ROOMS = 256
MAX_VERTICES = 128
MAX_NAME_LEN = 64
MAX_COORD_M = 100_000.0  # a building, not a map of the world
MAX_HEIGHT_M = 1000.0  # as an anchor's z (pfdoa.site.MAX_HEIGHT_M)
MIN_FLOOR_ANCHORS = 3
FLOOR_KEYS = schema.names_of("floors")
ROOM_KEYS = schema.names_of("rooms")

FLOOR_TOP = 2  # strongest readings per floor that make its evidence
FLOOR_SCALE_DB = 4.0  # dB of evidence per e-fold of likelihood (the spread of a floor's strongest readings)
SILENT_DBM = -105.0  # the evidence of a floor none of whose anchors heard the set
FLOOR_DWELL_S = 30.0  # mean time between floor changes the filter expects
MIN_SWITCH = 1e-3  # a floor change is never ruled out, even between two sets at one time
ROOM_SAMPLES = 512  # points of the position's Gaussian that measure room_p (+-2 % at worst)
MIN_VARIANCE = 1e-6  # m^2: a singular covariance is floored to this

# Fixed standard-normal points: room_p is a function of the estimate only (same every run).
_UNIT = np.random.default_rng(0x51).standard_normal((ROOM_SAMPLES, 2))


@dataclass(frozen=True)
class Floor:
    name: str
    zmin: float
    zmax: float  # exclusive
    target_z: float | None = None  # the beacon's height on this floor ([[floors]] target_z); None: the default

    def holds(self, z: float) -> bool:
        return self.zmin <= z < self.zmax


@dataclass(frozen=True)
class Room:
    name: str
    floor: str | None
    polygon: tuple[tuple[float, float], ...]

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Which of ``points`` (m, 2) are inside (ray casting; a point on an edge may go either way)."""
        return inside(np.asarray(points, dtype=float).reshape(-1, 2), np.asarray(self.polygon, dtype=float))


@dataclass(frozen=True)
class Plan:
    """A site's floors (file order), rooms (file order) and each anchor's floor (site order,
    an index into ``floors``; empty without floors)."""

    floors: tuple[Floor, ...]
    rooms: tuple[Room, ...]
    anchor_floors: tuple[int, ...] = ()

    def floor_index(self, name: str) -> int:
        return next(i for i, f in enumerate(self.floors) if f.name == name)

    @property
    def floors_with_anchors(self) -> tuple[int, ...]:
        return tuple(sorted(set(self.anchor_floors)))


def inside(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Ray casting: which of ``points`` (m, 2) lie inside ``polygon`` (k, 2), vectorised."""
    x, y = points[:, :1], points[:, 1:2]
    x0, y0 = polygon[:, 0], polygon[:, 1]
    x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (np.count_nonzero(crosses & (x < xs), axis=1) % 2) == 1


# -- parsing --------------------------------------------------------------------------------
def _number(source: str, key: str, v: Any, bound: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ConfigError(source, key, f"must be a number, got {_short(v)}")
    try:
        f = float(v)
    except OverflowError:  # a TOML integer beyond float range
        f = math.inf
    if not math.isfinite(f) or abs(f) > bound:
        raise ConfigError(source, key, f"must be a finite number within +-{bound:g}, got {_short(v)}")
    return f


def _short(v: Any) -> str:
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


def _name(source: str, key: str, v: Any) -> str:
    if not isinstance(v, str) or not 1 <= len(v) <= MAX_NAME_LEN or not v.isprintable():
        raise ConfigError(source, key, f"must be 1 to {MAX_NAME_LEN} printable characters, got {_short(v)}")
    return v


def _tables(source: str, key: str, value: Any, most: int) -> list[dict]:
    if not isinstance(value, list) or not all(isinstance(e, dict) for e in value):
        raise ConfigError(source, key, f"must be an array of tables ([[{key}]])")
    if not value:
        raise ConfigError(source, key, f"an empty array: list at least one [[{key}]] entry, or leave it out")
    if len(value) > most:
        raise ConfigError(source, key, f"at most {most} entries, got {len(value)}")
    return value


def _keys(source: str, where: str, entry: dict, known: tuple[str, ...]) -> None:
    for k in entry:
        if k not in known:
            raise ConfigError(source, f"{where}.{k}", f"unknown key (known: {', '.join(known)})")


def _floors(source: str, value: Any) -> tuple[Floor, ...]:
    out: list[Floor] = []
    for i, e in enumerate(_tables(source, "floors", value, MAX_FLOORS)):
        where = f"floors[{i}]"
        _keys(source, where, e, FLOOR_KEYS)
        schema.required(source, where, e, schema.keys_of("floors"))
        target = None
        if "target_z" in e:
            target = schema.check_value(source, f"{where}.target_z", schema.row("floors", "target_z"), e["target_z"])
        name = _name(source, f"{where}.name", e["name"])
        z = e["z"]
        if not isinstance(z, list) or len(z) != 2:
            raise ConfigError(source, f"{where}.z", f"must be [zmin, zmax] (m), got {_short(z)}")
        zmin, zmax = (_number(source, f"{where}.z", v, MAX_HEIGHT_M) for v in z)
        if not zmin < zmax:
            raise ConfigError(source, f"{where}.z", f"needs zmin < zmax, got {_short(z)}")
        for prev in out:
            if prev.name == name:
                raise ConfigError(source, f"{where}.name", f"duplicate floor name {name!r}")
            if zmin < prev.zmax and prev.zmin < zmax:
                raise ConfigError(source, f"{where}.z", f"overlaps floor {prev.name!r} "
                                  f"[{prev.zmin:g}, {prev.zmax:g}]")
        out.append(Floor(name, zmin, zmax, target))
    return tuple(out)


def _segments_meet(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Whether segments a-b and c-d (arrays of points, (m, 2) each) cross or touch."""
    def orient(p, q, r):
        return np.sign((q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0]))

    def on(p, q, r):  # r (collinear with p-q) within the segment's box
        return ((np.minimum(p[:, 0], q[:, 0]) <= r[:, 0]) & (r[:, 0] <= np.maximum(p[:, 0], q[:, 0]))
                & (np.minimum(p[:, 1], q[:, 1]) <= r[:, 1]) & (r[:, 1] <= np.maximum(p[:, 1], q[:, 1])))

    o1, o2, o3, o4 = orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b)
    return (((o1 * o2 < 0) & (o3 * o4 < 0)) | ((o1 == 0) & on(a, b, c)) | ((o2 == 0) & on(a, b, d))
            | ((o3 == 0) & on(c, d, a)) | ((o4 == 0) & on(c, d, b)))


def _polygon(source: str, key: str, value: Any) -> tuple[tuple[float, float], ...]:
    if not isinstance(value, list) or not 3 <= len(value) <= MAX_VERTICES:
        raise ConfigError(source, key, f"must be a list of 3 to {MAX_VERTICES} [x, y] points, got {_short(value)}")
    pts = []
    for v in value:
        if not isinstance(v, list) or len(v) != 2:
            raise ConfigError(source, key, f"each point must be [x, y] (m), got {_short(v)}")
        pts.append((_number(source, key, v[0], MAX_COORD_M), _number(source, key, v[1], MAX_COORD_M)))
    if len(set(pts)) < len(pts):
        raise ConfigError(source, key, "a point is listed twice (list each corner once, in order around the room)")
    p = np.array(pts)
    q = np.roll(p, -1, axis=0)
    if abs(float(np.sum(p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]))) < 1e-9:
        raise ConfigError(source, key, "encloses no area")
    k = len(p)
    i, j = np.triu_indices(k, 2)
    keep = ~((i == 0) & (j == k - 1))  # the last edge meets the first at point 0
    i, j = i[keep], j[keep]
    if np.any(_segments_meet(p[i], q[i], p[j], q[j])):
        raise ConfigError(source, key, "edges cross or touch: not a simple polygon (list the corners in order "
                          "around the room)")
    # Two edges in a row that fold back onto each other (a spike) also touch beyond their corner.
    prev = np.roll(p, 1, axis=0)
    e1, e2 = p - prev, q - p
    cross = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    if np.any((cross == 0) & (np.sum(e1 * e2, axis=1) < 0)):
        raise ConfigError(source, key, "two edges fold back onto each other: not a simple polygon")
    return tuple(pts)


def _rooms(source: str, value: Any, floors: tuple[Floor, ...]) -> tuple[Room, ...]:
    out: list[Room] = []
    names = {f.name for f in floors}
    for i, e in enumerate(_tables(source, "rooms", value, MAX_ROOMS)):
        where = f"rooms[{i}]"
        _keys(source, where, e, ROOM_KEYS)
        for k in ("name", "polygon"):
            if k not in e:
                raise ConfigError(source, f"{where}.{k}", "missing key")
        name = _name(source, f"{where}.name", e["name"])
        if any(r.name == name for r in out):
            raise ConfigError(source, f"{where}.name", f"duplicate room name {name!r}")
        floor = None
        if floors:
            if "floor" not in e:
                raise ConfigError(source, f"{where}.floor", f"missing key (one of the [[floors]]: "
                                  f"{', '.join(sorted(names))})")
            floor = _name(source, f"{where}.floor", e["floor"])
            if floor not in names:
                raise ConfigError(source, f"{where}.floor", f"no [[floors]] entry is named {floor!r} "
                                  f"(known: {', '.join(sorted(names))})")
        elif "floor" in e:
            raise ConfigError(source, f"{where}.floor", "the site has no [[floors]]: declare them, or leave this out")
        out.append(Room(name, floor, _polygon(source, f"{where}.polygon", e["polygon"])))
    return tuple(out)


def parse_plan(sections: Mapping[str, Any], anchor_z: Sequence[float], source: str = "<site>") -> Plan | None:
    """The site's ``[[floors]]`` and ``[[rooms]]`` (None when it has neither); ``anchor_z``
    are its anchors' heights in site order. ConfigError naming the key."""
    if "floors" not in sections and "rooms" not in sections:
        return None
    floors = _floors(source, sections["floors"]) if "floors" in sections else ()
    rooms = _rooms(source, sections["rooms"], floors) if "rooms" in sections else ()
    anchor_floors: list[int] = []
    if floors:
        for i, z in enumerate(anchor_z):
            k = next((j for j, f in enumerate(floors) if f.holds(z)), None)
            if k is None:
                raise ConfigError(source, f"anchors[{i}].z", f"{z:g} m is on none of the [[floors]] "
                                  f"({', '.join(f'{f.name} [{f.zmin:g}, {f.zmax:g})' for f in floors)})")
            anchor_floors.append(k)
        for j, f in enumerate(floors):
            n = anchor_floors.count(j)
            if 0 < n < MIN_FLOOR_ANCHORS:
                raise ConfigError(source, f"floors[{j}]", f"{f.name!r} holds {n} anchor{'s' * (n != 1)}: a floor "
                                  f"with anchors needs at least {MIN_FLOOR_ANCHORS} (its estimates use them alone)")
    return Plan(floors, rooms, tuple(anchor_floors))


def floor_targets(plan: Plan, target_z: float) -> tuple[float, ...]:
    """The beacon's height on each floor (plan order): the floor's ``target_z``, else
    ``target_z`` (``[site] target_z``, or a beacon's own) plus the floor's ``zmin`` above the
    lowest floor's: ``[site] target_z`` is the beacon's height on the lowest floor."""
    if not plan.floors:
        return ()
    base = min(f.zmin for f in plan.floors)
    return tuple(f.target_z if f.target_z is not None else target_z + f.zmin - base for f in plan.floors)


def floor_site(site):
    """``site`` as an estimator stepped with one floor's anchors at a time sees it (the
    localizer masks every set to the estimated floor's anchors, :meth:`Places.mask`): each
    anchor's height above the beacon on its own floor (:func:`floor_targets`), not above one
    ``target_z`` for the whole building (upper-floor anchors would look a floor too high).
    ``site`` itself without floors."""
    plan = site_plan(site)
    if plan is None or not plan.floors:
        return site
    from dataclasses import replace

    targets = floor_targets(plan, site.target_z)
    return replace(site, anchor_target_z=tuple(targets[f] for f in plan.anchor_floors))


def site_plan(site) -> Plan | None:
    """The plan of a loaded :class:`pfdoa.site.Site` (None without floors and rooms)."""
    return parse_plan(site.sections, [a.z for a in site.anchors], site.name or "<site>")


# -- locating -------------------------------------------------------------------------------
@dataclass(frozen=True)
class Place:
    """Where one estimate is (the output's ``floor``, ``floor_p``, ``room``, ``room_p``)."""

    floor: str | None = None
    floor_p: float | None = None
    room: str | None = None
    room_p: float | None = None


def gaussian_points(x: float, y: float, cov: tuple[float, float, float]) -> np.ndarray:
    """:data:`ROOM_SAMPLES` fixed points of the Gaussian at (x, y) with covariance (xx, xy, yy)
    (eigenvalues floored to :data:`MIN_VARIANCE`)."""
    xx, xy, yy = cov
    w, v = np.linalg.eigh(np.array([[xx, xy], [xy, yy]], dtype=float))
    root = v * np.sqrt(np.maximum(w, MIN_VARIANCE))
    return np.array([x, y]) + _UNIT @ root.T


class Places:
    """The floor filter and the room of one beacon's estimates (see the module doc).

    ``offsets``: the site's per-anchor RSSI offsets (site order), removed before the readings
    are compared between floors."""

    def __init__(self, plan: Plan, offsets: np.ndarray) -> None:
        self.plan = plan
        self.offsets = np.asarray(offsets, dtype=float)
        self.candidates = plan.floors_with_anchors  # floors the beacon can be found on
        af = np.array(plan.anchor_floors, dtype=int)
        self._members = [np.flatnonzero(af == f) for f in self.candidates]
        self._belief: np.ndarray | None = None
        self._t = -math.inf

    @property
    def multi_floor(self) -> bool:
        """Anchors on several floors: each set is estimated with its floor's anchors alone."""
        return len(self.candidates) > 1

    def reset(self) -> None:
        self._belief, self._t = None, -math.inf

    def floor(self, t: float, rssi: np.ndarray) -> tuple[int | None, float | None]:
        """One set's readings (dBm, site order, NaN = not heard) at time ``t``: the floor
        (an index into ``plan.floors``) and its probability; (None, None) without floors."""
        if not self.candidates:
            return None, None
        if len(self.candidates) == 1:
            return self.candidates[0], 1.0
        c = np.asarray(rssi, dtype=float) - self.offsets
        score = np.empty(len(self.candidates))
        for k, members in enumerate(self._members):
            heard = c[members]
            heard = np.sort(heard[np.isfinite(heard)])[::-1][:FLOOR_TOP]
            score[k] = heard.mean() if heard.size else SILENT_DBM
        loglik = (score - score.max()) / FLOOR_SCALE_DB
        n = len(self.candidates)
        if self._belief is None:
            prior = np.full(n, 1.0 / n)
        else:
            dt = t - self._t if math.isfinite(self._t) else 0.0
            switch = min(0.5, max(MIN_SWITCH, 1.0 - math.exp(-max(dt, 0.0) / FLOOR_DWELL_S)))
            prior = (1.0 - switch) * self._belief + switch / n
        post = prior * np.exp(loglik)
        post /= post.sum()
        self._belief, self._t = post, max(self._t, t)
        k = int(np.argmax(post))
        return self.candidates[k], float(post[k])

    def mask(self, rssi: np.ndarray, floor: int | None) -> np.ndarray:
        """The readings with every anchor that is not on ``floor`` set to not heard."""
        if floor is None or not self.multi_floor:
            return rssi
        out = np.array(rssi, dtype=float, copy=True)
        out[np.asarray(self.plan.anchor_floors) != floor] = np.nan
        return out

    def place(self, x: float, y: float, cov: tuple[float, float, float] | None, floor: int | None,
              floor_p: float | None) -> Place:
        """The room of an estimate at (x, y) with covariance ``cov`` (None: unknown) on ``floor``."""
        fname = None if floor is None else self.plan.floors[floor].name
        if not (math.isfinite(x) and math.isfinite(y)):
            return Place(fname, floor_p)
        point = np.array([[x, y]])
        room = next((r for r in self.plan.rooms if (r.floor is None or r.floor == fname) and r.contains(point)[0]),
                    None)
        if room is None:
            return Place(fname, floor_p)
        p = None
        if cov is not None and all(math.isfinite(v) for v in cov):
            p = float(np.mean(room.contains(gaussian_points(x, y, cov)))) * (1.0 if floor_p is None else floor_p)
        return Place(fname, floor_p, room.name, p)
