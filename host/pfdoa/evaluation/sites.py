"""Real sites for the evaluation: folders of recorded runs, and which runs are held out.

A site folder holds a site file and its runs in the common formats::

    <site>/site.toml or <site>/anchors.json    anchor positions (site.toml wins if both exist)
    <site>/<run>.csv[.gz]                      t,anchor,rssi_dbm,gt_x,gt_y[,seq]
    <site>/<run>.odom.csv[.gz]                 optional: t,dx,dy,dtheta

``anchors.json`` (the shared data folder's metadata) gives ``"anchors": [[x, y], ...]``;
the trace's ``anchor`` column is the index into that list. Its radio values are a neutral
guess (calibration fits them). :func:`find_sites` takes a folder that is a site, or a folder
of sites.

Which runs calibrate and which are scored (:func:`pairs`): every run is calibrated on one
run and scored with that calibration; a run is never scored with its own calibration (a site
of one run is scored with its site file as given). For
the committed development sites the roles are fixed in :data:`PROTOCOLS` (decisions looked
at the development runs only, see docs/archive/estimator-study.md); any other site, and any run of a
committed site that the protocol does not name, is scored against every other run (or, for
a committed site, calibrated on each of its development runs). A committed *held-out site*
(a protocol without development runs) is scored as a new site is, each run calibrated on
each other run, and every figure of it is held out: no decision looks at it.

A committed site is recognised by its runs' contents, not by names (:func:`protocol_for`): a
folder holding some of its development runs, under any folder or file names, gets its
protocol (those runs develop, every other run is held out). A folder with a committed site's
site file (same content: :func:`known_room`) but none of its development runs, such as other
tracks of that room, gets those runs from the package when found by :func:`find_sites`: its
own runs are then held out and calibrated on them, as the room's own held-out runs are. Any
other folder, whatever its name, is a new site, cross-calibrated, and its figures are not
in-sample.

Which group a site's figures belong to (:func:`decision_group`): **development** (decisions
looked at it: a committed development site, or a local one whose runs are listed in
``data/local_development.json``, the rooms whose dataset states no licence), **held-out** (a
committed held-out site) or **new** (anything else: a user's or a judge's own site). Reports
keep the three apart, and the studies in tools/ score development sites only, so a site
becomes a development site by being listed, never by being found in a folder.

The deployment protocol (``pairs(ts, "walk")``, ``pfdoa eval --sites DIR --calibration walk``,
``make eval-sites``) judges a site as a new user meets it: each run calibrated on ONE other
run alone (what ``pfdoa calibrate`` of one walk writes: no uncertainty factors measured on
further runs) and scored, every ordered pair, and each run scored uncalibrated (the site file's
neutral model, no walk). Held-out runs never calibrate; their pairs, and every pair of a
held-out site, carry the held-out roles (:data:`HELD_OUT_ROLES`): no decision may look at
them, and the report keeps them apart.
"""

from __future__ import annotations

import argparse
import functools
import gzip
import hashlib
import json
import logging
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pfdoa.errors import InputError
from pfdoa.evaluation.datasets import DATA_DIR, TraceSet, run_name, trace_set

# Re-exported: it lives with the site loader (datasets, which this module imports: no cycle).
from pfdoa.evaluation.datasets import site_from_anchors_json as site_from_anchors_json

log = logging.getLogger(__name__)

SITE_FILES = ("site.toml", "anchors.json")

HELD_OUT = "held-out"
DEVELOPMENT = "development"
NEW = "new"  # a site no decision here looked at, as far as its contents tell (decision_group)
CROSS = "cross-calibrated"
AS_GIVEN = "site as given"
# The deployment protocol's roles ("walk"): calibrated on one other run, or not at all.
ONE_WALK = "one walk"
UNCALIBRATED = "uncalibrated"
ONE_WALK_HELD = "one walk, held out"
UNCALIBRATED_HELD = "uncalibrated, held out"
WALK_ROLES = (ONE_WALK, UNCALIBRATED, ONE_WALK_HELD, UNCALIBRATED_HELD)
HELD_OUT_ROLES = (HELD_OUT, ONE_WALK_HELD, UNCALIBRATED_HELD)
CALIBRATIONS = ("auto", "cross", "none", "walk")


@dataclass(frozen=True)
class Protocol:
    develop: tuple[str, ...]  # runs that decisions looked at (calibrated on and scored)
    held_out: tuple[str, ...]  # runs no decision looked at: scored only, calibrated on each development run
    note: str = ""

    @property
    def whole_site(self) -> bool:
        """A held-out site: no decision looked at any of its runs, so each run is calibrated on
        each other run (they are its calibration data as a user's would be) and all are held out."""
        return not self.develop


UJI_NOTE = ("a held-out site: first scored on 2026-12-05 with the defaults as they stood, and no decision "
            "has looked at it; every run is calibrated on each other run")

PROTOCOLS: dict[str, Protocol] = {
    # One whole recording session (trial2: one run of each of the three experiments) held out.
    "herolab_wifi_robot": Protocol(
        develop=("trial1_exp2_1", "trial1_exp3_1", "trial1_exp4_1", "trial_exp2", "trial_exp3", "trial_exp4"),
        held_out=("trial2_exp2_2", "trial2_exp3_2", "trial2_exp4_2"),
        note="held out of every decision since the held-out protocol exists (issue 12); the earlier "
             "path-loss exponent floor was decided on all nine runs",
    ),
    # The six other tracks of the dataset (tools/convert_philotuxo.py, issue 47) joined the
    # development runs when they were added, before any scoring of them.
    "philotuxo_ble_dev": Protocol(
        develop=("straight_01", "zigzagging_with_rotation", "rectangular_without_rotation", "straight_02",
                 "straight_03", "straight_04", "straight_05", "zigzagging_without_rotation"),
        held_out=("rectangular_with_rotation",),
        note="rectangular_with_rotation was never scored before the final evaluation; the other six tracks "
             "joined the development runs in issue 47",
    ),
    # The same hall's stationary reference points (tools/convert_philotuxo.py --points): two sets
    # recorded on different dates, each calibrated on the other. Decisions look at it since the
    # report's misfit multiple (issue 47), the first decision that did.
    "philotuxo_ble_points": Protocol(develop=("set_1", "set_2"), held_out=(),
                                     note="two sets of static points, each calibrated on the other; both are "
                                          "development data (first scored as a new site)"),
    # Two runs only: each is calibrated on the other and scored, both ways (both are development data).
    "kolakowski_ble_dev": Protocol(develop=("calib1", "calib2"), held_out=(),
                                   note="only two runs: cross-calibrated both ways; both are development data"),
    # Whole sites held out (a phone at reference points, stop and go; tools/convert_uji_ble.py).
    "uji_ble_library": Protocol(
        develop=(), held_out=("a5_m12_c1", "a5_m12_c4", "bq_m12_c1", "bq_m12_c4", "s6_m12_c1", "s6_m12_c4"),
        note=UJI_NOTE,
    ),
    "uji_ble_lab": Protocol(develop=(), held_out=("a5_m04_c1", "a5_m12_c1", "a5_m20_c1"), note=UJI_NOTE),
    # Issue 47's sites. Scenario 1 of Pachos et al. (tools/convert_pachos.py): one room, three radios,
    # the dataset's two collections (the grid and the test points); Table I scored its grid before.
    **{f"pachos_{tech}": Protocol(develop=("fingerprints", "tests"), held_out=(),
                                  note="two collections, each calibrated on the other; the grid's figures with the "
                                       "paper's radio values stood in docs/results.md (Dataset 1) before")
       for tech in ("wifi", "ble", "zigbee")},
    # Szelinski & Nikodem's two diagonals (tools/convert_szelinski.py): a held-out site.
    "szelinski_ble_diag": Protocol(
        develop=(), held_out=("diag0", "diag1"),
        note="a held-out site since issue 47, when its runs were converted; diag0's figures with a radio model "
             "fitted on alternate points stood in docs/results.md (Dataset 2) before, diag1 was never scored"),
    # Feng, Nguyen & Luo's Wi-Fi office (tools/convert_feng_wifi.py): held out when converted and
    # scored once so (ratio 1.126, 79 % in r95, docs/sites.md of f281f3b), then a development site.
    "feng_wifi_office": Protocol(
        develop=("train", "test"), held_out=(),
        note="two sets of static points, each calibrated on the other; scored once as a held-out site when "
             "converted (2026-12-07), development data since"),
}
COMMITTED_SITES = tuple(PROTOCOLS)
# What each committed site is, for the reports (a site's anchors.json "technology" and "target"
# say it for sites converted since; these folders' files stay as the shared data has them).
SITE_KINDS: dict[str, tuple[str, str]] = {
    "herolab_wifi_robot": ("wifi", "robot, odometry"),
    "philotuxo_ble_dev": ("ble", "walking person"),
    "kolakowski_ble_dev": ("ble", "robot, stop and go"),
    "uji_ble_library": ("ble", "phone at static points"),
    "uji_ble_lab": ("ble", "phone at static points"),
}  # the sites converted since carry both in their anchors.json
DEVELOPMENT_SITES = tuple(name for name, p in PROTOCOLS.items() if not p.whole_site)  # what decisions may look at


# Site files these rooms were committed with before their heights were added (issue 47): a
# folder that still has one (the shared data's copy, a judge's other tracks) is the same room.
FORMER_SITE_FILES: dict[str, tuple[str, ...]] = {
    "philotuxo_ble_dev": ("62715d354b82c13f4064de84fa97a7aa7a5c7033b680c091802e399315e46f19",),
    "kolakowski_ble_dev": ("6100d979b7f89011aee9415c14a9a51a81b9093553c42bf2b2e5ed70c1d2fa7b",),
}


@functools.lru_cache(maxsize=4096)
def _content_digest(path: str) -> str:
    """SHA-256 of a file's text content: gzip or not, line endings normalised, so a copy of a
    committed run is recognised however it was stored ("" if unreadable: the loader says why)."""
    try:
        with (gzip.open if path.endswith(".gz") else open)(path, "rb") as fh:
            return hashlib.sha256(fh.read().replace(b"\r\n", b"\n")).hexdigest()
    except (OSError, EOFError, gzip.BadGzipFile):
        return ""


@functools.lru_cache(maxsize=1)
def _committed_contents() -> tuple[dict[str, tuple[str, int]], dict[str, str]]:
    """({development run digest (a held-out site's: any run's): (committed site, index in its
    protocol)}, {site file digest: committed site})."""
    runs: dict[str, tuple[str, int]] = {}
    rooms: dict[str, str] = {}
    for name, protocol in PROTOCOLS.items():
        ts = site_folder(DATA_DIR / name, odometry=False)
        for k, run in enumerate(protocol.held_out if protocol.whole_site else protocol.develop):
            runs[_content_digest(ts.run(run)[1])] = (name, k)
        for f in SITE_FILES:
            if (DATA_DIR / name / f).is_file():
                rooms[_content_digest(str(DATA_DIR / name / f))] = name
        rooms.update(dict.fromkeys(FORMER_SITE_FILES.get(name, ()), name))
    runs.pop("", None)
    rooms.pop("", None)
    return runs, rooms


def protocol_for(ts: TraceSet) -> tuple[str, Protocol] | None:
    """(committed site, its protocol in ``ts``'s run names) when ``ts`` holds some of that
    site's development runs (by content, whatever the folder and file names); None otherwise.
    Runs of ``ts`` that are not development runs are held out. A folder holding runs of a
    held-out site gets that site's protocol: every run held out."""
    known = _committed_contents()[0]
    found: dict[str, list[tuple[int, str]]] = {}  # committed site -> (index in its protocol, run)
    for run, path, _odo in ts.runs:
        hit = known.get(_content_digest(path))
        if hit is not None:
            found.setdefault(hit[0], []).append((hit[1], run))
    if not found:
        return None
    name = max(sorted(found), key=lambda n: len(found[n]))  # several sites' runs mixed: the most
    if PROTOCOLS[name].whole_site:
        return name, Protocol((), tuple(ts.run_names), PROTOCOLS[name].note)
    develop = tuple(run for _k, run in sorted(found[name]))  # in the protocol's order
    held = tuple(r for r in ts.run_names if r not in develop)
    return name, Protocol(develop, held, PROTOCOLS[name].note)


# The local development sites' run digests: {digest: site} (see the module's docstring).
LOCAL_DEVELOPMENT_FILE = DATA_DIR / "local_development.json"


@functools.lru_cache(maxsize=1)
def _local_development() -> dict[str, str]:
    doc = json.loads(LOCAL_DEVELOPMENT_FILE.read_text(encoding="utf-8"))
    return {digest: site for site, runs in doc["sites"].items() for digest in runs.values()}


def decision_group(ts: TraceSet) -> str:
    """:data:`DEVELOPMENT`, :data:`HELD_OUT` or :data:`NEW`: did decisions here look at ``ts``
    (by its runs' contents, whatever the names)? A folder holding runs of a development site is
    development (its other runs are held-out runs, :func:`walk_pairs`); one that holds none of
    ours, nor a listed local room's, is new. A cut or an edit of one of our runs is not
    recognised: it would count as new."""
    if held_out_site(ts):
        return HELD_OUT
    if protocol_for(ts) is not None:
        return DEVELOPMENT
    local = _local_development()
    return DEVELOPMENT if any(_content_digest(path) in local for _run, path, _odo in ts.runs) else NEW


def known_room(ts: TraceSet) -> str | None:
    """The committed site whose site file ``ts`` uses (same content), if any."""
    return _committed_contents()[1].get(_content_digest(ts.site_path))


def site_file(folder: Path) -> Path | None:
    for name in SITE_FILES:
        p = folder / name
        if p.is_file():
            return p
    return None


def runs_in(folder: Path) -> list[Path]:
    """Trace files of a site folder (odometry files excluded), sorted."""
    out = []
    for p in sorted(folder.iterdir()):
        name = p.name
        if p.is_file() and name.endswith((".csv", ".csv.gz")) and ".odom.csv" not in name:
            out.append(p)
    return out


def site_folder(folder: str | Path, *, odometry: bool = True, window_s: float | None = None,
                room_runs: bool = False) -> TraceSet:
    """The site in ``folder`` (a site file and at least one run); InputError otherwise.
    ``room_runs``: with its room's committed development runs where it has none of them
    (:func:`with_room_runs`)."""
    f = Path(folder)
    sf = site_file(f) if f.is_dir() else None
    if sf is None:
        raise InputError(f"{f}: not a site folder (needs {' or '.join(SITE_FILES)} and <run>.csv traces)")
    runs = runs_in(f)
    if not runs:
        raise InputError(f"{f}: no <run>.csv traces beside {sf.name}")
    ts = trace_set(f.name, sf, runs, odometry=odometry, window_s=window_s)
    return with_room_runs(ts, odometry=odometry, window_s=window_s) if room_runs else ts


def with_room_runs(ts: TraceSet, *, odometry: bool = True, window_s: float | None = None) -> TraceSet:
    """``ts`` with its room's committed development runs added when it uses a committed site's
    site file (:func:`known_room`) and holds none of them (other tracks of that room): its own
    runs are then held out and calibrated on them, as the room's held-out runs are
    (:func:`pairs`). Otherwise (or when one of its runs is named like one of them) ``ts``."""
    room = known_room(ts)
    if room is None or protocol_for(ts) is not None or PROTOCOLS[room].whole_site:
        return ts
    committed = {run_name(p): p for p in runs_in(DATA_DIR / room)}
    extra = [committed[r] for r in PROTOCOLS[room].develop]
    if any(run_name(p) in ts.run_names for p in extra):
        log.warning("%s: uses %s's site file but a run is named like one of its development runs: those are "
                    "not added, the runs calibrate each other", ts.name, room)
        return ts
    log.info("%s: %s's site file: its development runs (%s) calibrate these runs, which are held out",
             ts.name, room, ", ".join(PROTOCOLS[room].develop))
    return trace_set(ts.name, ts.site_path, [Path(r[1]) for r in ts.runs] + extra, odometry=odometry,
                     window_s=window_s)


def find_sites(root: str | Path, *, odometry: bool = True, window_s: float | None = None,
               room_runs: bool = True) -> tuple[TraceSet, ...]:
    """``root`` itself if it is a site folder, else every site folder directly inside it
    (``room_runs``: see :func:`site_folder`)."""
    r = Path(root)
    if not r.is_dir():
        raise InputError(f"{r}: no such folder")
    if site_file(r) is not None:
        return (site_folder(r, odometry=odometry, window_s=window_s, room_runs=room_runs),)
    found = tuple(site_folder(d, odometry=odometry, window_s=window_s, room_runs=room_runs) for d in site_dirs(r))
    if not found:
        raise InputError(f"{r}: {NO_SITES}")
    return found


NO_SITES = f"no site folders in it (each needs {' or '.join(SITE_FILES)} and <run>.csv traces)"


def site_dirs(root: Path) -> list[Path]:
    """The site folders directly inside ``root`` (a site file and at least one run), sorted."""
    return [d for d in sorted(root.iterdir()) if d.is_dir() and site_file(d) is not None and runs_in(d)]


def committed_sites(*, odometry: bool = True, window_s: float | None = None) -> tuple[TraceSet, ...]:
    """The sites committed in pfdoa/data: the development sites (the robot traces and two BLE
    sites) and the held-out ones (:attr:`Protocol.whole_site`)."""
    return tuple(site_folder(DATA_DIR / name, odometry=odometry, window_s=window_s) for name in COMMITTED_SITES)


def pairs(ts: TraceSet, calibration: str = "auto") -> list[tuple[str, str | None, str]]:
    """(role, calibration run or None, scored run) for every scoring of ``ts``.

    ``calibration``: "auto" (the protocol of the committed site whose development runs ``ts``
    holds, :func:`protocol_for`, else "cross"),
    "cross" (every run calibrated on every other run), "none" (the site file as given), "walk"
    (the deployment protocol, :func:`walk_pairs`). A site of one run is scored with its site
    file as given whatever ``calibration`` says.
    """
    runs = ts.run_names
    if calibration == "walk":
        return walk_pairs(ts)
    if calibration == "none" or len(runs) < 2:  # one run: no other run to calibrate it on
        return [(AS_GIVEN, None, r) for r in runs]
    found = protocol_for(ts) if calibration == "auto" else None
    if found is None:
        return [(CROSS, c, s) for c in runs for s in runs if c != s]
    dev, held = found[1].develop, found[1].held_out  # held: including runs the protocol never named
    if found[1].whole_site:  # as "cross", every run held out
        return [(HELD_OUT, c, s) for c in held for s in held if c != s]
    role = DEVELOPMENT if held else CROSS
    out: list[tuple[str, str | None, str]] = [(HELD_OUT, c, h) for h in held for c in dev]
    out += [(role, c, s) for s in dev for c in dev if c != s]
    return out


def walk_pairs(ts: TraceSet) -> list[tuple[str, str | None, str]]:
    """The deployment protocol: (role, calibration run or None, scored run) for every ordered
    pair of distinct runs (the scored run calibrated on the other one alone) and every run
    uncalibrated (None: the site file's neutral model). A held-out run never calibrates: it is
    scored calibrated on each development run, with the held-out roles; every pair of a
    held-out site is held out (:func:`protocol_for`, by content). A site without a protocol
    (a new site) is all development roles: nothing is held out of it."""
    found = protocol_for(ts)
    if found is None:
        dev, held = list(ts.run_names), []
    elif found[1].whole_site:
        dev, held = [], list(found[1].held_out)
    else:
        dev, held = list(found[1].develop), list(found[1].held_out)
    if not dev:  # a held-out site: its runs calibrate each other, every figure held out
        out: list[tuple[str, str | None, str]] = [(ONE_WALK_HELD, c, s) for s in held for c in held if c != s]
        return out + [(UNCALIBRATED_HELD, None, s) for s in held]
    out = [(ONE_WALK, c, s) for s in dev for c in dev if c != s]
    out += [(ONE_WALK_HELD, c, s) for s in held for c in dev]
    return out + [(UNCALIBRATED, None, s) for s in dev] + [(UNCALIBRATED_HELD, None, s) for s in held]


def held_out_site(ts: TraceSet) -> bool:
    """Is ``ts`` (recognised by its runs' contents) a site that no decision may look at?"""
    found = protocol_for(ts)
    return found is not None and found[1].whole_site


def development_sites(local: str | Path | None = None, *, odometry: bool = True) -> tuple[TraceSet, ...]:
    """The sites a decision may look at: the committed development sites and the listed local
    ones found in the folder ``local`` (the studies in tools/ score no other). A new site found
    there is skipped with a warning: listing it (``data/local_development.json``) is the
    decision to develop on it, and it then leaves the sites that can be reported as unseen."""
    found = list(committed_sites(odometry=odometry))
    if local is not None and Path(local).is_dir() and site_dirs(Path(local)):
        found += find_sites(local, odometry=odometry)
    groups = {ts.name: decision_group(ts) for ts in found}
    skipped = sorted(name for name, g in groups.items() if g == NEW)
    if skipped:
        log.warning("not development sites (not listed in %s), skipped: %s", LOCAL_DEVELOPMENT_FILE.name,
                    ", ".join(skipped))
    return tuple(ts for ts in found if groups[ts.name] == DEVELOPMENT)


def headline_role(roles: set[str]) -> str:
    """The role a site's headline figure comes from: held-out runs if any, else the cross-calibration."""
    for r in (HELD_OUT, CROSS, AS_GIVEN, DEVELOPMENT, *WALK_ROLES):
        if r in roles:
            return r
    raise ValueError("no roles")


def in_sample(role: str, ts: TraceSet) -> str:
    """Whether figures of ``role`` are in-sample: did a decision look at those runs?"""
    if role in HELD_OUT_ROLES:
        return "not in-sample: no decision looked at these runs"
    if decision_group(ts) == DEVELOPMENT:
        return "in-sample: decisions looked at these runs"
    room = known_room(ts)
    if room is not None:
        kind = "held-out" if PROTOCOLS[room].whole_site else "development"
        return f"not in-sample: no decision looked at these runs (the room is {kind} site {room}'s)"
    # Runs are known by their whole content: a cut or an edit of a committed run is not.
    return "in-sample unknown: neither the site file nor a run is a committed site's (a cut of a committed run would be in-sample)"


# ----------------------------------------------------------------------------- converted sites
CONVERTED_RADIO = (-60.0, 2.0)  # the neutral guess every converter writes (A dBm at 1 m, n): calibration fits it
# What a converter's bad input raises: a missing file or column, a bad number, a failed check,
# a truncated archive.
CONVERT_ERRORS = (OSError, KeyError, ValueError, IndexError, EOFError)


def converter_parser(doc: str) -> argparse.ArgumentParser:
    """The command line of a converter in tools/: its module doc's first paragraph as the
    description, the rest (where there is more) as the epilog."""
    head, _, rest = doc.partition("\n\n")
    return argparse.ArgumentParser(description=head, epilog=rest or None,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)


def run_converter(name: str, convert: Callable[[], object]) -> int:
    """Run a converter's ``convert``: 0, or 2 with one line ``name: why`` on stderr where its
    data is missing or malformed (:data:`CONVERT_ERRORS`)."""
    try:
        convert()
    except CONVERT_ERRORS as exc:
        print(f"{name}: {exc}", file=sys.stderr)
        return 2
    return 0


def write_site_folder(folder: Path, anchors, comments, meta: dict, *, heights: tuple | None = None) -> None:
    """A converted site's ``site.toml`` (the one site-file writer, :func:`pfdoa.site.site_to_toml`,
    under ``comments`` as ``#`` lines; the neutral radio guess; ``heights``: (every anchor's z,
    the beacon's target_z) where the source gives both) and its ``anchors.json`` (the folder's
    name, then ``meta``: source, licence, technology, target, anchors, caveats, ...)."""
    import json

    from pfdoa.radio import PathLoss
    from pfdoa.site import Anchor, Site, site_to_toml

    zs, target_z = heights if heights is not None else ([0.0] * len(anchors), 0.0)
    site = Site(PathLoss(*CONVERTED_RADIO), tuple(Anchor(k, float(x), float(y), z=float(z))
                                                   for k, ((x, y), z) in enumerate(zip(anchors, zs))),
                target_z=float(target_z))
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "site.toml").write_text("".join(f"# {c}\n" for c in comments) + site_to_toml(site))
    (folder / "anchors.json").write_text(json.dumps({"name": folder.name, **meta}, indent=1) + "\n")


def write_run(path: Path, rows) -> int:
    """A run in the common trace format (the one writer, :class:`pfdoa.sinks.readings.ReadingsCsvSink`)
    from rows of (t s, anchor id, RSSI dBm, gt_x, gt_y), one per reading in order: each reading
    its own ground truth; gzipped with mtime 0 (the same bytes every time) when ``path`` ends in
    ``.gz``. Returns the number of readings."""
    import io

    from pfdoa.readings.reassembly import Reading
    from pfdoa.sinks.readings import ReadingsCsvSink

    rows = list(rows)
    truth = iter([(gx, gy) for _t, _a, _r, gx, gy in rows])
    buf = io.StringIO()
    sink = ReadingsCsvSink(buf, ground_truth=lambda _t: next(truth), flush_each=False)
    for t, a, r, _gx, _gy in rows:
        sink.reading(Reading(int(a), float(r), float(t), None))
    if str(path).endswith(".gz"):
        with gzip.GzipFile(path, "wb", mtime=0) as fh:
            fh.write(buf.getvalue().encode())
    else:
        Path(path).write_text(buf.getvalue())
    return len(rows)
