"""`pfdoa anchors` against four QEMU anchors (the Cortex-M3 firmware image, each on its own
pseudo-terminal, the simulator injecting its radio readings in real time): listed with
their STATUS, a fitted site's offsets applied, acked, confirmed by their next STATUS, and
their next reports moved by exactly those offsets. Outcomes only, never timing."""

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
from pfdoa.protocol import defs

from qemu_support import build_qemu_images

OFFSETS = {1: -1.25, 2: 2.5, 3: 0.0, 4: 0.5}


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
    finally:
        stop_sim(sim)
    predicted = predicted_reports(tmp_path / "trace.csv")
    assert check_shift(before, predicted, {a: 0 for a in OFFSETS}) >= 4 * 4
    assert check_shift(after, predicted, {a: offset_config(o).offset_q8 for a, o in OFFSETS.items()}) >= 4 * 4
