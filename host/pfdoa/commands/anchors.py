"""pfdoa anchors: list anchors with their STATUS; set configuration and beacon filters, verified."""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
from typing import Any

HELP = "list anchors with their STATUS; set their configuration, beacon filters or a site's offsets"
DESCRIPTION = """\
Talk to anchors over the gateway's transports (serial ports and CAN buses: every anchor
on a line or bus answers the frames addressed to it). Standard input is not
bidirectional: --stdin can only list.

  list      every anchor heard within --listen seconds, with its STATUS: firmware, uptime,
            configuration hash, counters, schema (protocol version), beacon filter table
            hash and slots, and the beacon entries its reports were about. With --config,
            stops once every anchor of the site has sent a STATUS, names the ones that did
            not, and compares their hashes with the site's offsets and [[beacons]].
  set       send a configuration (CONFIG_SET) to --anchor N ... (or --all heard ones).
            CONFIG_SET replaces the whole configuration: fields not given take the
            protocol's defaults (protocol/SPEC.md 1.3).
  filters   set the beacon filter table (FILTER_SET, every entry) from a site's
            [[beacons]] (--config), or the first-boot table (--default). UART only.
  apply     SITE.toml: each of the site's anchors removes its rssi_offset_db itself
            (the offsets `pfdoa calibrate` fits: the anchor's offset is minus the site's),
            and the site's [[beacons]] become the anchors' filter table. Afterwards give
            the gateway a site file without those offsets (the anchors apply them now).
  keygen    FILE: write a new random key for an authenticated beacon (protocol/SPEC.md 9)
            to a new file readable by its owner only; name it in a [[beacons]] entry
            (kind = "pfdoa_auth", key_file = FILE) and give it to the beacon. Prints its
            key check value, never the key. `filters` / `apply` then put the key in the
            anchors' filter table over the link: do it on the installation's own line.
  beacon    give an authenticated beacon (the nRF52840 beacon image) its key (--key-file)
            and the time over its UART (--serial), checking its answers: the key check
            value it computes, the counter it runs. Without --key-file only the time
            (after a power cycle: the beacon keeps its key, not the time).

Each change is verified: the anchor's ack (our token, result, the new hash), its next
STATUS reporting that hash, and (configuration) its first report after the change
carrying the CALIBRATED flag exactly when the offset is not 0. An anchor that does not
ack within --reply-timeout is sent the message again, --retries times in all; the whole
command ends within --timeout. One line per anchor: done on standard output, failures
on standard error.
"""
EPILOG = """\
examples:
  pfdoa anchors list --serial /dev/ttyUSB0
  pfdoa anchors list --config site.toml --serial /dev/ttyACM0 --serial /dev/ttyACM1 --json
  pfdoa anchors set --serial /dev/ttyUSB0 --anchor 3 --offset-db -1.5
  pfdoa anchors set --can socketcan:can0 --all --alpha 0.125 --spike-db 8
  pfdoa anchors filters --serial /dev/ttyUSB0 --config site.toml
  pfdoa calibrate run.csv --config site.toml --out fitted.toml
  pfdoa anchors apply fitted.toml --serial /dev/ttyUSB0
  pfdoa anchors keygen robot1.key
  pfdoa anchors beacon --serial /dev/ttyACM0 --key-file robot1.key

exit status: 0 every anchor answered and every change was verified; 1 some did not (one
  line each on standard error); 2 bad arguments or site file; 130/143 stopped by
  SIGINT/SIGTERM (what was heard and each anchor's outcome printed first)
"""


def _add_common(p: argparse.ArgumentParser) -> None:
    from pfdoa.commands._common import add_input_options

    src = p.add_argument_group("transports (at least one)")
    add_input_options(src, "serial:URL[@BAUD], can:INTERFACE:CHANNEL[@BITRATE], stdin; pfdoa gateway --help: "
                           "input specs", "read a UART byte stream on standard input (list only)")
    t = p.add_argument_group("timing")
    t.add_argument("--listen", type=float, default=3.0, metavar="S",
                   help="list / --all: listen this long for anchors (default 3; a STATUS comes every second)")
    t.add_argument("--reply-timeout", type=float, default=1.0, metavar="S",
                   help="send again when an anchor has not acked within S (default 1)")
    t.add_argument("--retries", type=int, default=3, metavar="N", help="sends of one message at most (default 3)")
    t.add_argument("--status-timeout", type=float, default=3.0, metavar="S",
                   help="wait this long for the STATUS (and report) that confirm a change (default 3)")
    t.add_argument("--timeout", type=float, default=30.0, metavar="S", help="the whole command at most (default 30)")
    p.add_argument("--json", action="store_true", help="print the result as one JSON document")


def _add_config(p: argparse.ArgumentParser) -> None:
    from pfdoa.anchors import REPORT_MODE_NAMES
    from pfdoa.protocol import defs

    c = p.add_argument_group("configuration (CONFIG_SET replaces all of it; the defaults are the protocol's)")
    c.add_argument("--alpha", type=float, default=defs.DEFAULT_ALPHA_Q8 / 256.0, metavar="A",
                   help=f"EMA constant, 1/256..1 (default {defs.DEFAULT_ALPHA_Q8 / 256.0:g})")
    c.add_argument("--spike-db", type=int, default=defs.DEFAULT_SPIKE_DB, metavar="DB",
                   help=f"spike threshold in whole dB, 0 disables (default {defs.DEFAULT_SPIKE_DB})")
    c.add_argument("--report-mode", choices=REPORT_MODE_NAMES, default=REPORT_MODE_NAMES[defs.DEFAULT_REPORT_MODE],
                   help="every event, every --decimation-th event, or silent (STATUS only)")
    c.add_argument("--decimation", type=int, default=defs.DEFAULT_DECIMATION, metavar="N",
                   help=f"with --report-mode decimate (default {defs.DEFAULT_DECIMATION})")


def _add_targets(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("anchors")
    g.add_argument("--anchor", "-a", type=int, action="append", default=[], metavar="ID",
                   help="an anchor id; repeat for several")
    g.add_argument("--all", action="store_true", help="every anchor heard within --listen")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.epilog = EPILOG
    sub = p.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    kw: dict[str, Any] = {"formatter_class": argparse.RawDescriptionHelpFormatter}
    ls = sub.add_parser("list", help="anchors heard, with their STATUS", **kw)
    ls.add_argument("--config", "-c", metavar="SITE.toml", help="the site: its anchors are expected, hashes compared")
    _add_common(ls)
    st = sub.add_parser("set", help="set anchors' configuration (CONFIG_SET), verified", **kw)
    _add_targets(st)
    st.add_argument("--offset-db", type=float, default=0.0, metavar="DB",
                    help="calibration offset added to the filtered RSSI (default 0)")
    _add_config(st)
    _add_common(st)
    fl = sub.add_parser("filters", help="set anchors' beacon filter table (FILTER_SET), verified", **kw)
    fl.add_argument("--config", "-c", metavar="SITE.toml", help="the table from the site's [[beacons]]; "
                                                                "without --anchor/--all: the site's anchors")
    fl.add_argument("--default", action="store_true", help="the first-boot table (our beacon id 0 only)")
    _add_targets(fl)
    _add_common(fl)
    ap = sub.add_parser("apply", help="a fitted site's per-anchor offsets and its [[beacons]], verified", **kw)
    ap.add_argument("site", metavar="SITE.toml", help="a site file (e.g. from pfdoa calibrate --out)")
    _add_config(ap)
    _add_common(ap)
    kg = sub.add_parser("keygen", help="write a new authenticated beacon's key file (mode 0600)", **kw)
    kg.add_argument("key_file", metavar="FILE", help="the key file to create (never overwritten)")
    bc = sub.add_parser("beacon", help="an authenticated beacon's key and time over its UART, checked", **kw)
    bc.add_argument("--serial", "-s", required=True, metavar="URL[@BAUD]", help="the beacon's serial port")
    bc.add_argument("--key-file", metavar="FILE", help="its key file (pfdoa anchors keygen); omit to set the time only")
    bc.add_argument("--reply-timeout", type=float, default=2.0, metavar="S",
                    help="wait this long for each answer (default 2)")
    bc.add_argument("--json", action="store_true", help="print the beacon's state as one JSON document")


def _transports(args):
    """The inputs the options name, through the gateway's input registry: each one anchor
    link (a CAN bus, or one byte stream: a serial port, standard input); ``set``, ``filters``
    and ``apply`` need ones that can send (InputError otherwise)."""
    from pfdoa.errors import InputError
    from pfdoa.gateway.inputs import InputContext, backend, make_inputs, specs_from_args

    specs = specs_from_args(args)
    if not specs:
        raise InputError("no transport: give --serial, --can or --stdin (or --input SPEC)")
    for s in specs:
        cls = backend(s.kind)
        if not (cls.is_can or cls.decoder_sources == 1):  # a capture, the broker: many links in one
            raise InputError(f"{s.where()}: pfdoa anchors needs inputs that are one link to the anchors each (a "
                             "serial port, a CAN bus, standard input)")
    out = make_inputs(specs, InputContext())
    for t in out:
        if args.action != "list" and not t.bidirectional:
            raise InputError(f"{t.where} is not bidirectional: 'pfdoa anchors {args.action}' must send to the anchors "
                             "(use --serial or --can)")
    return out


def _timing(args):
    from pfdoa.anchors import Timing
    from pfdoa.errors import InputError

    for name in ("listen", "reply_timeout", "status_timeout", "timeout"):
        v = getattr(args, name)
        if not (v > 0 and math.isfinite(v)):
            raise InputError(f"--{name.replace('_', '-')} must be a finite number > 0, got {v}")
    if not 1 <= args.retries <= 100:
        raise InputError(f"--retries must be in 1..100, got {args.retries}")
    return Timing(reply_timeout_s=args.reply_timeout, retries=args.retries, status_timeout_s=args.status_timeout,
                  total_timeout_s=args.timeout)


def _base_config(args):
    """The configuration fields other than the offset, from the options (InputError if invalid)."""
    from pfdoa.anchors import REPORT_MODE_NAMES
    from pfdoa.errors import InputError
    from pfdoa.protocol import defs
    from pfdoa.protocol.config import AnchorConfig

    alpha_q8 = int(round(args.alpha * 256.0)) if math.isfinite(args.alpha) else 0
    if not defs.VALID_ALPHA_Q8_MIN <= alpha_q8 <= defs.VALID_ALPHA_Q8_MAX:
        raise InputError(f"--alpha must be in [{defs.VALID_ALPHA_Q8_MIN}/256, {defs.VALID_ALPHA_Q8_MAX}/256], "
                         f"got {args.alpha}")
    if not 0 <= args.spike_db <= 255:
        raise InputError(f"--spike-db must be in 0..255, got {args.spike_db}")
    if not defs.VALID_DECIMATION_MIN <= args.decimation <= defs.VALID_DECIMATION_MAX:
        raise InputError(f"--decimation must be in {defs.VALID_DECIMATION_MIN}..{defs.VALID_DECIMATION_MAX}, "
                         f"got {args.decimation}")
    return AnchorConfig(alpha_q8=alpha_q8, spike_db=args.spike_db,
                        report_mode=REPORT_MODE_NAMES.index(args.report_mode), decimation=args.decimation)


def _targets(args, mgr, fallback=None) -> list[int]:
    """The anchors to change (--all: those heard within --listen; mgr None: only check)."""
    from pfdoa.errors import InputError
    from pfdoa.protocol import defs

    for a in args.anchor:
        if not 0 <= a <= defs.ANCHOR_ID_MAX:
            raise InputError(f"--anchor {a}: an anchor id is 0..{defs.ANCHOR_ID_MAX}")
    if args.anchor and args.all:
        raise InputError("--anchor and --all: give one of them")
    if args.all:
        return sorted(mgr.listen(args.listen)) if mgr is not None else []
    if args.anchor:
        return sorted(set(args.anchor))
    if fallback is not None:
        return list(fallback)
    raise InputError(f"pfdoa anchors {args.action}: which anchors? give --anchor ID or --all")


def _site_hashes(site) -> dict[int, int | None]:
    """The configuration hash ``apply`` would give each of the site's anchors (None: its
    offset is beyond what an anchor holds, so none of them has it)."""
    from pfdoa.anchors import offset_config
    from pfdoa.errors import InputError

    out: dict[int, int | None] = {}
    for a in site.anchors:
        try:
            out[a.id] = offset_config(a.rssi_offset_db).hash
        except InputError:
            out[a.id] = None
    return out


def _print_list(heard: dict, site, bcfg, args, as_json: bool, ended: str = "") -> int:
    expected = site.anchor_ids if site is not None else None
    missing = [a for a in expected if a not in heard or heard[a].status is None] if expected else []
    cfg_hash = _site_hashes(site) if site is not None else {}
    within = ended or f"within {args.listen:g} s"
    site_filters = bcfg.filter_hash if bcfg is not None else None
    rows = []
    for a, info in heard.items():
        d = info.as_dict()
        s = info.status
        if site is not None and s is not None:
            # config_as_site: the anchor holds what `apply` sets for the site (it removes the
            # site's offset itself; the other fields the protocol's defaults).
            d["site"] = {"in_site": a in cfg_hash,
                         "config_as_site": s.config_hash == cfg_hash.get(a),
                         "filters_match": None if site_filters is None or not s.filter_slots
                         else s.filter_hash == site_filters}
        rows.append(d)
    if as_json:
        print(json.dumps({"anchors": rows, "missing": missing}, indent=1))
    else:
        print("anchor  link      fw     uptime  config  schema  filters/slots  dropped rx_err spikes  reports  beacons")
        for d in rows:
            s = d["status"]
            if s is None:
                print(f"{d['anchor']:>6}  {d['link']:<8}  (no STATUS yet)                                         "
                      f"{d['reports']:>7}  {','.join(map(str, d['beacons'])) or '-'}")
                continue
            filt = f"0x{s['filter_hash']:04x}/{s['filter_slots']}" if s["filter_hash"] is not None else "-"
            note = ""
            if "site" in d:
                x = d["site"]
                note = ("  (not in the site)" if not x["in_site"] else
                        "  config " + ("= site" if x["config_as_site"] else "differs from the site's offsets")
                        + ("" if x["filters_match"] is None else
                           ", filters " + ("= site" if x["filters_match"] else "differ from the site's")))
            if "peers" in d:  # the anchors it hears (peer readings, docs/anchors.md)
                note += "  hears anchors " + ",".join(map(str, d["peers"]))
            print(f"{d['anchor']:>6}  {d['link']:<8}  {s['firmware']:<5} {s['uptime_s']:>7}s  0x{s['config_hash']:04x}"
                  f"  {d['schema']:<6}  {filt:<13}  {s['dropped_events']:>7} {s['rx_errors']:>6} {s['spikes']:>6}"
                  f"  {d['reports']:>7}  {','.join(map(str, d['beacons'])) or '-'}{note}")
    for a in missing:
        print(f"pfdoa: anchors: anchor {a}: no STATUS {within}", file=sys.stderr)
    if not heard:
        print(f"pfdoa: anchors: no anchor heard {within}", file=sys.stderr)
        return 1
    return 1 if missing else 0


def _report(outcomes: dict, as_json: bool, what: str) -> int:
    """One line per anchor (failures on standard error); 0 when every one is done."""
    done = [o for o in outcomes.values() if o.ok]
    if not as_json:
        for o in done:
            print(o.message)
        print(f"{what}: {len(done)} of {len(outcomes)} anchors done")
    for o in outcomes.values():
        if not o.ok:
            print(f"pfdoa: anchors: {o.message}", file=sys.stderr)
    return 0 if len(done) == len(outcomes) else 1


def _keygen(path: str) -> int:
    from pfdoa.errors import InputError
    from pfdoa.gateway.auth import write_key_file
    from pfdoa.protocol.auth import key_check

    try:
        key = write_key_file(path)
    except FileExistsError:
        raise InputError(f"{path}: exists (a key file is never overwritten: revoke the old key by giving the "
                         "beacon and the anchors a new one)") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot create it ({exc.strerror or exc})") from None
    print(f"wrote {path} (mode 0600): key check {key_check(key)[:4].hex()}")
    return 0


def _beacon(args) -> int:
    import serial

    from pfdoa.beacon_setup import BeaconError, BeaconLink, provision
    from pfdoa.errors import ConfigError, InputError
    from pfdoa.gateway.auth import load_key_file
    from pfdoa.gateway.inputs.serial import split_baud

    if not (args.reply_timeout > 0 and math.isfinite(args.reply_timeout)):
        raise InputError(f"--reply-timeout must be a finite number > 0, got {args.reply_timeout}")
    key = None
    if args.key_file:
        try:
            key = load_key_file(args.key_file, args.key_file, "key")
        except ConfigError as exc:
            raise InputError(str(exc)) from None
    url, baud = split_baud(args.serial, 115200)
    try:
        port = serial.serial_for_url(url, baudrate=baud, timeout=0.05)
    except (ValueError, serial.SerialException, OSError) as exc:
        raise InputError(f"--serial {url}: {exc}") from None
    try:
        state = provision(BeaconLink(port, args.reply_timeout), key)
    except BeaconError as exc:
        print(f"pfdoa: anchors: {exc}", file=sys.stderr)
        return 1
    finally:
        port.close()
    if args.json:
        print(json.dumps(state.as_dict()))
    else:
        print(f"beacon on {url}: key check {state.key_check}, counter {state.counter}, "
              f"{state.sent} advertisements sent, {state.failures} send failures")
    return 0


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from pfdoa import signals
    from pfdoa.anchors import AnchorManager, offset_config, offset_q8
    from pfdoa.errors import InputError
    from pfdoa.gateway.beacons import beacons_config
    from pfdoa.outfiles import stdout_guard
    from pfdoa.protocol import default_table
    from pfdoa.site import load_site

    log = logging.getLogger("pfdoa.anchors")
    if args.action == "keygen":
        return _keygen(args.key_file)
    if args.action == "beacon":
        return _beacon(args)
    timing = _timing(args)
    site = bcfg = None
    path = getattr(args, "site", None) or getattr(args, "config", None)
    if path:
        site = load_site(path)
        bcfg = beacons_config(site.sections, str(path))
    if args.action == "filters":
        if args.default == bool(site):
            raise InputError("pfdoa anchors filters: give --config SITE.toml (its [[beacons]]) or --default")
        if bcfg is not None and bcfg.table() is None:
            raise InputError(f"{path}: no [[beacons]] to set as the anchors' filter table")
    # Every argument is checked before a port is opened.
    base = _base_config(args) if args.action in ("set", "apply") else None
    if args.action == "set":
        assert base is not None  # _base_config for "set"
        base = replace(base, offset_q8=offset_q8(args.offset_db, "--offset-db"))  # the anchor's own, added to its RSSI
    offsets = {}
    if args.action == "apply":  # each anchor's, checked as `set` checks --offset-db
        assert site is not None and base is not None
        offsets = {a.id: offset_config(a.rssi_offset_db, base, f"{path}: anchor {a.id}: its offset (minus "
                                       f"rssi_offset_db {a.rssi_offset_db:g})") for a in site.anchors}
    if args.action in ("set", "filters"):
        _targets(args, None, fallback=site.anchor_ids if site is not None else None)
    transports = _transports(args)
    # SIGINT/SIGTERM end the listening and the retries (pfdoa.signals): what was heard and
    # done is printed, then the one line and 130/143.
    sig = signals.active()
    with AnchorManager(transports, timing=timing, stop=sig.event) as mgr, sig.graceful(), stdout_guard():
        if args.action == "list":
            log.info("listening up to %g s on %s", args.listen, ", ".join(t.name for t in transports))
            heard = mgr.listen(args.listen, until=site.anchor_ids if site is not None else None)
            rc = _print_list(heard, site, bcfg, args, args.json,
                             ended="before the stop" if sig.stopped else "before the input ended" if mgr.ended else "")
        else:
            results: dict[str, dict] = {}
            if args.action == "set":
                assert base is not None
                results["configuration"] = mgr.configure({a: base for a in _targets(args, mgr)})
            elif args.action == "filters":
                table = default_table() if bcfg is None else bcfg.table()
                assert table is not None  # checked above
                targets = _targets(args, mgr, fallback=site.anchor_ids if site is not None else None)
                results["filter table"] = mgr.set_filters({a: table for a in targets})
            else:  # apply: the positional SITE.toml is loaded above
                assert site is not None and bcfg is not None
                results["offsets"] = mgr.configure(offsets)
                applied = bcfg.table()
                if applied is not None:
                    results["filter table"] = mgr.set_filters({a: applied for a in site.anchor_ids})
            rc = 0
            for what, outcomes in results.items():
                rc |= _report(outcomes, args.json, what)
            if args.json:
                print(json.dumps({what: [o.as_dict() for o in outcomes.values()] for what, outcomes in results.items()},
                                 indent=1))
            elif args.action == "apply" and site is not None:
                _offsets_note(site, path, results["offsets"])
        errors = mgr.decode_errors
        if errors:
            log.warning("frames rejected on the links: %s", " ".join(f"{k}={v}" for k, v in errors.items()))
    sig.raise_if_stopped("while listening (what was heard is listed above)" if args.action == "list" else
                         "before every anchor was done (each one's outcome is above)")
    return rc


def _offsets_note(site, path, outcomes: dict) -> None:
    """What the gateway's site file must now say: only the anchors that did take their
    offset remove it themselves (the others still need it in the site file)."""
    applied = [a.id for a in site.anchors if a.rssi_offset_db and a.id in outcomes and outcomes[a.id].ok]
    if not applied:
        return
    ids = ", ".join(map(str, applied))
    kept = [a.id for a in site.anchors if a.rssi_offset_db and a.id not in applied]
    print(f"note: anchor(s) {ids} now remove {path}'s rssi_offset_db themselves: give the gateway a site file with "
          "rssi_offset_db = 0 (or none) for them" + (f"; keep the offsets of anchor(s) {', '.join(map(str, kept))}, "
                                                      "which did not take theirs" if kept else ""))
