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

Other sections (``[estimator]``, ``[gateway]``, ...) are optional and kept as plain
dicts in :attr:`Site.sections` for the modules that own them to validate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pfdoa import _toml as tomllib
from pfdoa.errors import ConfigError

KNOWN_TOP_LEVEL = {"radio", "anchors", "estimator", "gateway", "output", "site", "beacons"}


@dataclass(frozen=True)
class Radio:
    """Log-distance path loss: RSSI(d) = rssi_at_1m_dbm - 10 * n * log10(d) + offset."""

    rssi_at_1m_dbm: float
    path_loss_exponent: float


@dataclass(frozen=True)
class Anchor:
    id: int
    x: float
    y: float
    rssi_offset_db: float = 0.0


@dataclass(frozen=True)
class Site:
    radio: Radio
    anchors: tuple[Anchor, ...]
    name: str = ""
    sections: dict[str, Any] = field(default_factory=dict)

    @property
    def anchor_ids(self) -> tuple[int, ...]:
        return tuple(a.id for a in self.anchors)

    @property
    def positions(self) -> np.ndarray:
        """Anchor positions, shape (n_anchors, 2), in site order."""
        return np.array([[a.x, a.y] for a in self.anchors], dtype=float)

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
        raise ConfigError(src, key, f"must be a number, got {type(value).__name__} {value!r}")
    try:
        finite = math.isfinite(float(value))
    except OverflowError:  # a TOML integer beyond float range (fuzz/regressions/site)
        finite = False
    if not finite:
        raise ConfigError(src, key, f"must be a finite number, got {value!r}")
    return float(value)


def parse_site(data: dict[str, Any], source: str = "<site>") -> Site:
    """Validate a parsed TOML document and build a :class:`Site`."""
    if not isinstance(data, dict):
        raise ConfigError(source, "<document>", "must be a TOML table")
    radio = data.get("radio")
    if radio is None:
        raise ConfigError(source, "radio", "missing section [radio]")
    if not isinstance(radio, dict):
        raise ConfigError(source, "radio", "must be a table ([radio])")
    for key in ("rssi_at_1m_dbm", "path_loss_exponent"):
        if key not in radio:
            raise ConfigError(source, f"radio.{key}", "missing key")
    a1m = _number(source, "radio.rssi_at_1m_dbm", radio["rssi_at_1m_dbm"])
    n = _number(source, "radio.path_loss_exponent", radio["path_loss_exponent"])
    if not 0.5 <= n <= 10.0:
        raise ConfigError(source, "radio.path_loss_exponent", f"must be in [0.5, 10], got {n}")
    for key in radio:
        if key not in ("rssi_at_1m_dbm", "path_loss_exponent"):
            raise ConfigError(source, f"radio.{key}", "unknown key")

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
        for key in ("id", "x", "y"):
            if key not in entry:
                raise ConfigError(source, f"{where}.{key}", "missing key")
        aid = entry["id"]
        if isinstance(aid, bool) or not isinstance(aid, int):
            raise ConfigError(source, f"{where}.id", f"must be an integer, got {aid!r}")
        if not 0 <= aid <= 126:
            raise ConfigError(source, f"{where}.id", f"must be in 0..126, got {aid}")
        if aid in seen:
            raise ConfigError(source, f"{where}.id", f"duplicate anchor id {aid}")
        seen.add(aid)
        x = _number(source, f"{where}.x", entry["x"])
        y = _number(source, f"{where}.y", entry["y"])
        off = _number(source, f"{where}.rssi_offset_db", entry.get("rssi_offset_db", 0.0))
        for key in entry:
            if key not in ("id", "x", "y", "rssi_offset_db", "name"):
                raise ConfigError(source, f"{where}.{key}", "unknown key")
        anchors.append(Anchor(id=aid, x=x, y=y, rssi_offset_db=off))

    pts = np.array([[a.x, a.y] for a in anchors])
    centred = pts - pts.mean(axis=0)
    extent = float(np.abs(centred).max()) or 1.0
    sv = np.linalg.svd(centred / extent, compute_uv=False)
    if sv[-1] < 1e-6 * max(sv[0], 1e-12) or sv[0] == 0.0:
        raise ConfigError(source, "anchors", "anchor positions are collinear (need a 2-D spread)")

    for key in data:
        if key not in KNOWN_TOP_LEVEL:
            raise ConfigError(source, key, "unknown section")
    sections = {k: v for k, v in data.items() if k not in ("radio", "anchors")}
    for k, v in sections.items():
        # [[beacons]] may be an array (pfdoa.gateway.beacons.beacons_config validates it).
        if not isinstance(v, dict) and not (k == "beacons" and isinstance(v, list)):
            raise ConfigError(source, k, "must be a table")
    name = str(sections.get("site", {}).get("name", Path(source).parent.name if source != "<site>" else ""))
    return Site(radio=Radio(a1m, n), anchors=tuple(anchors), name=name, sections=sections)


def load_site(path: str | Path) -> Site:
    """Read and validate a site TOML file. Raises :class:`ConfigError` (exit code 2)."""
    p = Path(path)
    src = str(p)
    try:
        raw = p.read_bytes()
    except OSError as exc:
        raise ConfigError(src, "<file>", f"cannot read: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise ConfigError(src, "<file>", "not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(src, "<syntax>", str(exc)) from None
    return parse_site(data, src)


def site_to_toml(site: Site) -> str:
    """Serialise the minimal contract (and the optional offsets) back to TOML."""
    lines = []
    if site.name:
        lines += ["[site]", f'name = "{site.name}"', ""]
    lines += [
        "[radio]",
        f"rssi_at_1m_dbm = {site.radio.rssi_at_1m_dbm:.4f}",
        f"path_loss_exponent = {site.radio.path_loss_exponent:.4f}",
    ]
    for a in site.anchors:
        lines += ["", "[[anchors]]", f"id = {a.id}", f"x = {a.x!r}", f"y = {a.y!r}"]
        if a.rssi_offset_db != 0.0:
            lines.append(f"rssi_offset_db = {a.rssi_offset_db:.4f}")
    return "\n".join(lines) + "\n"
