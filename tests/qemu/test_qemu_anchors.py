"""`pfdoa anchors` against four QEMU anchors (the Cortex-M3 firmware image, each on its own
pseudo-terminal, the simulator injecting its radio readings in real time): listed with
their STATUS, a fitted site's offsets and [[beacons]] applied, acked, confirmed by their
next STATUS (the filter table stored in the port's .noinit store: acked with result 0,
not "applied, not stored"), their next reports moved by exactly those offsets, and the
first-boot filter table set back with `filters --default`. Outcomes only, never timing."""

import re

from anchors_support import (
    anchors_cmd,
    check_shift,
    fitted_site,
    predicted_reports,
    read_reports,
    start_sim,
    stop_sim,
    wait_for,
)

from pfdoa.anchors import offset_config
from pfdoa.gateway.beacons import beacons_config
from pfdoa.protocol import defs
from pfdoa.site import load_site

from qemu_support import build_qemu_images

OFFSETS = {1: -1.25, 2: 2.5, 3: 0.0, 4: 0.5}
# Our beacon stays entry 0 (its reports keep coming), an iBeacon that nobody sends is entry 1.
BEACONS = ('\n[[beacons]]\nname = "robot"\nkind = "pfdoa"\n\n[[beacons]]\nname = "tag"\nkind = "ibeacon"\n'
           'uuid = "f7826da6-4fa2-4e98-8024-bc5b71e0893e"\nmajor = 1\nminor = 2\nperiod_ms = 50\n')


def test_qemu_anchors_are_listed_and_take_a_sites_offsets(tmp_path):
    build_qemu_images()
    sim = start_sim(tmp_path, "--anchor-backend", "qemu")
    try:
        def ports():
            found = re.findall(r"QEMU anchor (\d+) \(.*\) on (\S+)", (tmp_path / "sim.out").read_text())
            return dict((int(a), p) for a, p in found) if len(found) == 4 else None

        by_anchor = wait_for(ports, "four QEMU ptys", sim)
        serial = [x for a in sorted(by_anchor) for x in ("--serial", by_anchor[a])]
        site = tmp_path / "site.toml"
        rc, doc, err = anchors_cmd("list", *serial, "--config", str(site), "--listen", "60")
        assert rc == 0, err
        rows = {r["anchor"]: r for r in doc["anchors"]}
        assert sorted(rows) == [1, 2, 3, 4]
        for a, r in rows.items():
            assert r["link"] == f"serial{a - 1}" and r["schema"] == "v2"  # each anchor on its own port
            assert r["status"]["config_hash"] == defs.CONFIG_DEFAULT_HASH
            assert r["status"]["filter_slots"] == defs.BEACON_SLOTS

        ports_list = [by_anchor[a] for a in sorted(by_anchor)]
        before = read_reports(ports_list, 5, OFFSETS)
        fitted = fitted_site(site, OFFSETS, tmp_path / "fitted.toml")
        rc, doc, err = anchors_cmd("apply", str(fitted), *serial)
        assert rc == 0, err
        for o in doc["offsets"]:
            want = offset_config(OFFSETS[o["anchor"]]).hash
            assert o["ok"] and o["acked_hash"] == o["status_hash"] == want and o["report_checked"], o
        after = read_reports(ports_list, 5, OFFSETS)

        # The same site with [[beacons]]: apply sets the filter table too (a changed entry
        # restarts its filter, so the report check above comes first).
        with_beacons = tmp_path / "beacons.toml"
        with_beacons.write_text(fitted.read_text() + BEACONS)
        filter_hash = beacons_config(load_site(with_beacons).sections).filter_hash
        assert filter_hash != defs.FILTER_TABLE_DEFAULT_HASH
        rc, doc, err = anchors_cmd("apply", str(with_beacons), *serial)
        assert rc == 0, err
        assert all(o["ok"] for o in doc["offsets"]), doc["offsets"]
        assert [(o["anchor"], o["ok"], o["status_hash"]) for o in doc["filter table"]] == [
            (a, True, filter_hash) for a in (1, 2, 3, 4)], doc["filter table"]
        rc, doc, err = anchors_cmd("list", *serial, "--config", str(with_beacons), "--listen", "60")
        assert rc == 0 and all(r["site"]["filters_match"] for r in doc["anchors"]), (err, doc)
        rc, doc, err = anchors_cmd("filters", *serial, "--default", "--all", "--listen", "8")
        assert rc == 0, err
        assert [(o["anchor"], o["ok"], o["status_hash"]) for o in doc["filter table"]] == [
            (a, True, defs.FILTER_TABLE_DEFAULT_HASH) for a in (1, 2, 3, 4)], doc["filter table"]
    finally:
        stop_sim(sim)
    predicted = predicted_reports(tmp_path / "trace.csv")
    assert check_shift(before, predicted, {a: 0 for a in OFFSETS}) >= 4 * 4
    assert check_shift(after, predicted, {a: offset_config(o).offset_q8 for a, o in OFFSETS.items()}) >= 4 * 4
