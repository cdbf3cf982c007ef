"""Site configuration: anchor positions and the radio model, read from TOML.

The minimal contract (other tools and recorded datasets rely on it)::

    [radio]
    rssi_at_1m_dbm = -45.0
    path_loss_exponent = 2.2
    [[anchors]]
    id = 0
    x = 0.0
    y = 0.0
    # rssi_offset_db = 0.0   (optional, per anchor)
    # z = 2.5                (optional, m: the anchor's height; default 0)

``[site] target_z`` (m, optional, default 0) is the beacon's height; with anchor heights it
makes every distance 3-D. Both default to 0, so a file without them means what it always did.

Other sections (``[estimator]``, ``[gateway]``, ``[output]``) are optional and kept as
plain dicts in :attr:`Site.sections` for the modules that own them to validate; ``[site]``
holds only ``name`` (a string). Unknown sections and keys are errors, so a typo never
passes silently.

Every table and key, its type, range and default: :mod:`pfdoa.schema` (docs/site-file.md),
which this module and every other validator of a table take them from.

The file is untrusted in syntax and types (docs/security.md): at most ``MAX_FILE_BYTES``
are read, a UTF-8 byte order mark is allowed, values nest at most ``MAX_DEPTH`` deep, and
anything else wrong is a :class:`~pfdoa.errors.ConfigError` naming the file and the key.
:func:`site_to_toml` is the one writer of site files (``pfdoa calibrate``, the simulator):
what it writes loads back to the same :class:`Site`, and writing that again gives the
same text.
"""

from __future__ import annotations

import datetime
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pfdoa import _toml as tomllib
from pfdoa import schema
from pfdoa.errors import ConfigError
from pfdoa.protocol.defs import ANCHOR_ID_MAX
from pfdoa.radio import PathLoss

log = logging.getLogger(__name__)

# Tables, keys, types, ranges and defaults: pfdoa.schema (docs/site-file.md is generated from it).
KNOWN_TOP_LEVEL = set(schema.TOP_LEVEL)
SITE_KEYS = schema.names_of("site")  # the [site] table
ARRAY_SECTIONS = ("beacons", "floors", "rooms")  # arrays of tables ([[beacons]] may also be a table)
ANCHOR_KEYS = schema.names_of("anchors")
MAX_HEIGHT_M = schema.MAX_HEIGHT_M
MAX_FILE_BYTES = 1 << 20  # a site file is a few KB; /dev/zero or a wrong file must not fill memory
MAX_DEPTH = 16  # tables and arrays inside each other; deeper is not a site file (and not recursed into)
# The path-loss exponents a site file accepts (pfdoa calibrate holds a lower fit at the minimum;
# pf-doa models less: the schema's row says what it does, and loading warns).
_EXPONENT = schema.row("radio", "path_loss_exponent")
MIN_PATH_LOSS_EXPONENT = float(_EXPONENT.min or 0.0)
MAX_PATH_LOSS_EXPONENT = float(_EXPONENT.max or 0.0)
# A site file's anchor ids: any a recorded dataset may use (a trace's anchor column). Only our
# frames narrow them, to 0..ANCHOR_ID_MAX: see require_wire_ids.
SITE_ANCHOR_ID_MAX = schema.SITE_ANCHOR_ID_MAX


@dataclass(frozen=True)
class Anchor:
    id: int
    x: float
    y: float
    rssi_offset_db: float = 0.0
    name: str = ""  # optional label, kept so that a written site file keeps it
    z: float = 0.0  # height (m); 0 with target_z 0 is the plane of old files


@dataclass(frozen=True)
class Site:
    radio: PathLoss
    anchors: tuple[Anchor, ...]
    name: str = ""
    sections: dict[str, Any] = field(default_factory=dict)
    # (xmin, ymin, xmax, ymax) m: where the target can be ([site] area); None: around the anchors
    area: tuple[float, float, float, float] | None = None
    target_z: float = 0.0  # the beacon's height (m), [site] target_z
    # Per anchor (site order), the beacon's height its height is measured from, in place of
    # target_z: with [[floors]], the beacon on the anchor's own floor (pfdoa.rooms.floor_site).
    # Derived, never written; () = target_z for every anchor.
    anchor_target_z: tuple[float, ...] = ()

    @property
    def anchor_ids(self) -> tuple[int, ...]:
        return tuple(a.id for a in self.anchors)

    @property
    def positions(self) -> np.ndarray:
        """Anchor positions, shape (n_anchors, 2), in site order."""
        return np.array([[a.x, a.y] for a in self.anchors], dtype=float)

    @property
    def heights(self) -> np.ndarray:
        """Anchor heights above the target's plane (m): z - target_z (``anchor_target_z``
        where given), shape (n_anchors,). Zero everywhere for a site without heights, so 3-D
        distances equal 2-D ones."""
        if self.anchor_target_z:
            return np.array([a.z - t for a, t in zip(self.anchors, self.anchor_target_z)], dtype=float)
        return np.array([a.z - self.target_z for a in self.anchors], dtype=float)

    @property
    def offsets(self) -> np.ndarray:
        """Per-anchor RSSI offsets (dB), shape (n_anchors,), in site order."""
        return np.array([a.rssi_offset_db for a in self.anchors], dtype=float)

    def index_of(self, anchor_id: int) -> int:
        """Index of an anchor id in site order; KeyError if unknown."""
        for i, a in enumerate(self.anchors):
            if a.id == anchor_id:
                return i
        raise KeyError(anchor_id)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the anchors."""
        p = self.positions
        return float(p[:, 0].min()), float(p[:, 1].min()), float(p[:, 0].max()), float(p[:, 1].max())


def _number(src: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(src, key, f"must be a number, got {type(value).__name__} {_short(value)}")
    try:
        finite = math.isfinite(float(value))
    except OverflowError:  # a TOML integer beyond float range (fuzz/regressions/site)
        finite = False
    if not finite:
        raise ConfigError(src, key, f"must be a finite number, got {_short(value)}")
    return float(value)


def _short(value: Any) -> str:
    r = repr(value)
    return r if len(r) <= 60 else r[:57] + "..."


def _check_depth(source: str, data: Any) -> None:
    """Values nested more than MAX_DEPTH deep are an error (iterative: no recursion here)."""
    stack = [(data, 0, "<document>")]
    while stack:
        v, depth, where = stack.pop()
        if depth > MAX_DEPTH:
            raise ConfigError(source, where, f"nested more than {MAX_DEPTH} levels deep")
        # The error names the key of a table (section.key, anchors[i].key), not the deep path.
        if isinstance(v, dict):
            stack.extend((x, depth + 1, k if where == "<document>" else (f"{where}.{k}" if depth < 2 else where))
                         for k, x in v.items())
        elif isinstance(v, list):
            stack.extend((x, depth + 1, f"{where}[{i}]" if depth < 1 else where) for i, x in enumerate(v))


def parse_site(data: dict[str, Any], source: str = "<site>") -> Site:
    """Validate a parsed TOML document and build a :class:`Site`."""
    if not isinstance(data, dict):
        raise ConfigError(source, "<document>", "must be a TOML table")
    _check_depth(source, data)
    radio = data.get("radio")
    if radio is None:
        raise ConfigError(source, "radio", "missing section [radio]")
    if not isinstance(radio, dict):
        raise ConfigError(source, "radio", "must be a table ([radio])")
    schema.check_keys(source, "radio", radio, schema.names_of("radio"))
    schema.required(source, "radio", radio, schema.keys_of("radio"))
    a1m = _checked(source, "radio", "rssi_at_1m_dbm", radio)
    n = _checked(source, "radio", "path_loss_exponent", radio)
    schema.modelled_notes(source, "radio", {"path_loss_exponent": n})

    raw_anchors = data.get("anchors")
    if raw_anchors is None:
        raise ConfigError(source, "anchors", "missing [[anchors]] entries")
    if not isinstance(raw_anchors, list):
        raise ConfigError(source, "anchors", "must be an array of tables ([[anchors]])")
    if len(raw_anchors) < 3:
        raise ConfigError(source, "anchors", f"need at least 3 anchors, got {len(raw_anchors)}")
    anchors: list[Anchor] = []
    seen: set[int] = set()
    for i, entry in enumerate(raw_anchors):
        where = f"anchors[{i}]"
        if not isinstance(entry, dict):
            raise ConfigError(source, where, "must be a table")
        schema.check_keys(source, where, entry, ANCHOR_KEYS)
        schema.required(source, where, entry, schema.keys_of("anchors"))
        aid = _checked(source, "anchors", "id", entry, where)
        if aid in seen:
            raise ConfigError(source, f"{where}.id", f"duplicate anchor id {aid}")
        seen.add(aid)
        x, y, off, z, label = (_checked(source, "anchors", k, entry, where)
                               for k in ("x", "y", "rssi_offset_db", "z", "name"))
        anchors.append(Anchor(id=aid, x=x, y=y, rssi_offset_db=off, name=label, z=z))

    pts = np.array([[a.x, a.y] for a in anchors])
    if float(np.ptp(pts, axis=0).max()) > MAX_AREA_SIDE_M:
        raise ConfigError(source, "anchors", f"anchors more than {MAX_AREA_SIDE_M:g} m apart: a building, not a "
                          "country (positions in metres?)")
    centred = pts - pts.mean(axis=0)
    extent = float(np.abs(centred).max()) or 1.0
    sv = np.linalg.svd(centred / extent, compute_uv=False)
    if sv[-1] < 1e-6 * max(sv[0], 1e-12) or sv[0] == 0.0:
        raise ConfigError(source, "anchors", "anchor positions are collinear (need a 2-D spread)")

    for key in data:
        if key not in KNOWN_TOP_LEVEL:
            raise ConfigError(source, key, f"unknown section (known: {', '.join(sorted(KNOWN_TOP_LEVEL))})")
    sections = {k: v for k, v in data.items() if k not in ("radio", "anchors")}
    for k, v in sections.items():
        # Arrays of tables: their owners validate them (pfdoa.gateway.beacons, pfdoa.rooms).
        if not isinstance(v, dict) and not (k in ARRAY_SECTIONS and isinstance(v, list)):
            raise ConfigError(source, k, f"must be an array of tables ([[{k}]])" if k in ARRAY_SECTIONS[1:]
                              else f"must be a table ([{k}])")
    if "radio_map" in sections:  # pfdoa calibrate's map; checked here so a bad one fails at load
        from pfdoa.radiomap import parse_radio_map

        parse_radio_map(sections["radio_map"], [a.id for a in anchors], source)
    if "floors" in sections or "rooms" in sections:  # [[floors]], [[rooms]]: checked here so a bad one fails at load
        from pfdoa.rooms import parse_plan

        parse_plan(sections, [a.z for a in anchors], source)
    if isinstance(sections.get("estimator"), dict):
        sections["estimator"] = dict(sections["estimator"])
        _drop_retired_options(sections["estimator"], source)
    table = sections.get("site", {})
    schema.check_keys(source, "site", table, SITE_KEYS)
    if "name" in table:
        name = _checked(source, "site", "name", table)
    else:
        name = Path(source).parent.name if source != "<site>" else ""
    area = parse_area(source, "site.area", table["area"]) if "area" in table else None
    target_z = _checked(source, "site", "target_z", table)
    if "map_pose" in table:  # where the site frame lies in the map (pfdoa.frames)
        from pfdoa.frames import parse_map_pose

        parse_map_pose(source, table["map_pose"])
    return Site(radio=PathLoss(a1m, n), anchors=tuple(anchors), name=name, sections=sections, area=area,
                target_z=target_z)


MAX_COORDINATE_M = schema.MAX_COORDINATE_M  # a projected map's metres (UTM) fit; 1e308 is not a place


def _checked(src: str, table: str, key: str, entry: dict[str, Any], where: str | None = None) -> Any:
    """``entry[key]`` (its default when absent) checked by the schema's row of ``table.key``."""
    spec = schema.row(table, key)
    if key not in entry:
        return spec.default
    return schema.check_value(src, f"{where or table}.{key}", spec, entry[key])


def _drop_retired_options(table: dict[str, Any], source: str) -> None:
    """An [estimator] table that sets options an earlier pfdoa had (RETIRED_OPTIONS: among them
    the uncertainty factors and estimate gain `pfdoa calibrate` wrote) still loads: one warning
    names them, and they are dropped (so a file written back no longer carries them)."""
    from pfdoa.estimators.common import RETIRED_OPTIONS

    retired = sorted(k for k in table if k in RETIRED_OPTIONS)
    if retired:
        log.warning("%s: [estimator] %s: retired (docs/estimator.md), ignored", source, ", ".join(retired))
        for k in retired:
            del table[k]


MAX_AREA_SIDE_M = 10_000.0  # a building, not a country: bounds the estimators' grids


def parse_area(src: str, key: str, value: Any) -> tuple[float, float, float, float]:
    """``[xmin, ymin, xmax, ymax]`` in metres, each side positive and at most MAX_AREA_SIDE_M."""
    if not isinstance(value, list) or len(value) != 4:
        raise ConfigError(src, key, f"must be [xmin, ymin, xmax, ymax], got {_short(value)}")
    x0, y0, x1, y1 = (_number(src, key, v) for v in value)
    if not (x0 < x1 and y0 < y1):
        raise ConfigError(src, key, f"needs xmin < xmax and ymin < ymax, got {_short(value)}")
    if max(x1 - x0, y1 - y0) > MAX_AREA_SIDE_M:
        raise ConfigError(src, key, f"a side longer than {MAX_AREA_SIDE_M:g} m")
    return (x0, y0, x1, y1)


def load_site(path: str | Path) -> Site:
    """Read and validate a site TOML file. Raises :class:`ConfigError` (exit code 2)."""
    p = Path(path)
    src = str(p)
    try:
        # Bounded read: a FIFO or a pipe (`--config <(...)`) is read like a file, /dev/zero is not a site.
        with open(p, "rb") as fh:
            raw = fh.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise ConfigError(src, "<file>", f"cannot read: {exc.strerror or exc}") from None
    if len(raw) > MAX_FILE_BYTES:
        raise ConfigError(src, "<file>", f"larger than {MAX_FILE_BYTES // 1024} KiB: not a site file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise ConfigError(src, f"<line {line}>", "not UTF-8 text") from None
    try:
        data = tomllib.loads(text.removeprefix("\ufeff"))  # editors on Windows write a BOM
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(src, "<syntax>", str(exc)) from None
    except RecursionError:  # arrays or inline tables nested thousands deep
        raise ConfigError(src, "<syntax>", "values nested too deeply") from None
    except ValueError as exc:  # an integer of more than 4300 digits (Python's int() limit)
        raise ConfigError(src, "<syntax>", str(exc).split(":")[0]) from None
    return parse_site(data, src)


def require_wire_ids(site: Site, source: str, inputs: str) -> None:
    """ConfigError unless every anchor id fits our frames (0..ANCHOR_ID_MAX): anchors that
    report over ``inputs`` (named in the message) cannot have others. Recorded traces and
    ESPresense rooms may use any site id."""
    for i, a in enumerate(site.anchors):
        if a.id > ANCHOR_ID_MAX:
            raise ConfigError(source, f"anchors[{i}].id", f"{a.id} cannot come from {inputs}: our frames carry "
                              f"anchor ids 0..{ANCHOR_ID_MAX} (larger ids are for recorded traces and ESPresense rooms)")


# -- writing ------------------------------------------------------------------------------
_BARE_KEY = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_-")
_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}


def toml_string(s: str) -> str:
    """A TOML basic string: quote, backslash and control characters escaped (TOML 1.0 says
    which must be); every other character as it is (not JSON's surrogate-pair escapes,
    which TOML rejects)."""
    out = ['"']
    for ch in s:
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def toml_key(k: str) -> str:
    return k if k and all(c in _BARE_KEY for c in k) else toml_string(k)


def toml_value(v: Any) -> str:
    """One value as TOML (tables inline); ValueError for what TOML cannot hold."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)  # shortest exact form; 'inf', '-inf', 'nan' are TOML too
    if isinstance(v, str):
        return toml_string(v)
    if isinstance(v, (datetime.datetime, datetime.date, datetime.time)):
        return v.isoformat()
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{toml_key(k)} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise ValueError(f"cannot write {type(v).__name__} to TOML")


def site_to_toml(site: Site) -> str:
    """The whole site as TOML: ``[site]`` name, ``[radio]``, every anchor and every other
    section (``[gateway]``, ``[estimator]``, ``[output]``, ``[[beacons]]``) in order. The one writer of site
    files: ``load_site`` of the text gives the same site, and writing it again the same text."""
    lines: list[str] = []
    map_pose = site.sections.get("site", {}).get("map_pose")
    if site.name or site.area is not None or site.target_z != 0.0 or map_pose is not None:
        lines.append("[site]")
        if site.name:
            lines.append(f"name = {toml_string(site.name)}")
        if site.area is not None:
            lines.append(f"area = {toml_value([float(v) for v in site.area])}")
        if site.target_z != 0.0:
            lines.append(f"target_z = {toml_value(float(site.target_z))}")
        if map_pose is not None:
            lines.append(f"map_pose = {toml_value(map_pose)}")
        lines.append("")
    lines += [
        "[radio]",
        f"rssi_at_1m_dbm = {toml_value(float(site.radio.rssi_at_1m_dbm))}",
        f"path_loss_exponent = {toml_value(float(site.radio.path_loss_exponent))}",
    ]
    for a in site.anchors:
        lines += ["", "[[anchors]]", f"id = {int(a.id)}", f"x = {toml_value(float(a.x))}",
                  f"y = {toml_value(float(a.y))}"]
        if a.z != 0.0:
            lines.append(f"z = {toml_value(float(a.z))}")
        if a.rssi_offset_db != 0.0:
            lines.append(f"rssi_offset_db = {toml_value(float(a.rssi_offset_db))}")
        if a.name:
            lines.append(f"name = {toml_string(a.name)}")
    for name, table in site.sections.items():
        if name == "site" or not table:
            continue
        for entry in (table if isinstance(table, list) else [table]):  # [[beacons]] is an array of tables
            lines += ["", f"[[{toml_key(name)}]]" if isinstance(table, list) else f"[{toml_key(name)}]"]
            lines += [f"{toml_key(k)} = {toml_value(v)}" for k, v in entry.items()]
    return "\n".join(lines) + "\n"
