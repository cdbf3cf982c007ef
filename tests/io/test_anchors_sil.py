"""`pfdoa anchors` against the simulator's four anchors (the real firmware core) on a real
pseudo-terminal in real time (issue 16's must-show): they are listed with their STATUS,
a fitted site file's offsets are applied, acked and confirmed by their next STATUS, and
their next reports move by exactly those offsets. Outcomes only, never timing."""

import pytest
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

OFFSETS = {1: 1.5, 2: -2.0, 3: 0.75, 4: 3.0}  # rssi_offset_db as pfdoa calibrate fits them


def test_list_and_apply_offsets_verified_through_status_and_reports(tmp_path):
    link = tmp_path / "anchors.tty"
    sim = start_sim(tmp_path, "--transport", "pty", "--link", str(link))
    try:
        wait_for(lambda: link.exists() and (tmp_path / "site.toml").exists(), "pty", sim)
        site = tmp_path / "site.toml"
        rc, doc, err = anchors_cmd("list", "--serial", str(link), "--config", str(site), "--listen", "60")
        assert rc == 0, err
        rows = {r["anchor"]: r for r in doc["anchors"]}
        assert sorted(rows) == [1, 2, 3, 4] and doc["missing"] == []
        for r in rows.values():
            s = r["status"]
            assert r["schema"] == "v2" and s["version"] == defs.PROTO_VERSION and s["firmware"] == "1.0"
            assert s["config_hash"] == defs.CONFIG_DEFAULT_HASH and r["site"]["config_as_site"]
            assert s["filter_hash"] == defs.FILTER_TABLE_DEFAULT_HASH and s["filter_slots"] == defs.BEACON_SLOTS

        before = read_reports([str(link)], 5, OFFSETS)
        fitted = fitted_site(site, OFFSETS, tmp_path / "fitted.toml")
        rc, doc, err = anchors_cmd("apply", str(fitted), "--serial", str(link))
        assert rc == 0, err
        outcomes = {o["anchor"]: o for o in doc["offsets"]}
        assert sorted(outcomes) == [1, 2, 3, 4]
        for a, o in outcomes.items():
            want = offset_config(OFFSETS[a]).hash
            assert o["ok"] and o["acked_hash"] == o["status_hash"] == want and o["report_checked"], o
        after = read_reports([str(link)], 5, OFFSETS)
        rc, doc, err = anchors_cmd("list", "--serial", str(link), "--config", str(fitted), "--listen", "60")
        assert rc == 0 and all(r["site"]["config_as_site"] for r in doc["anchors"]), err
        # An anchor that is not there: one line, exit status 1, the others unaffected.
        rc, doc, err = anchors_cmd("set", "--serial", str(link), "--anchor", "9", "--anchor", "2",
                                   "--offset-db", "2", "--reply-timeout", "3", "--retries", "2",
                                   "--status-timeout", "20", "--timeout", "100")
        assert rc == 1 and [o["ok"] for o in doc["configuration"]] == [True, False]
        assert err.strip().splitlines() == ["pfdoa: anchors: anchor 9: no CONFIG_ACK after 2 tries (6 s)"]
    finally:
        stop_sim(sim)
    predicted = predicted_reports(tmp_path / "trace.csv")
    assert check_shift(before, predicted, {a: 0 for a in OFFSETS}) >= 4 * 4
    assert check_shift(after, predicted, {a: offset_config(o).offset_q8 for a, o in OFFSETS.items()}) >= 4 * 4


def test_filters_from_a_sites_beacons_and_back(tmp_path):
    link = tmp_path / "anchors.tty"
    sim = start_sim(tmp_path, "--transport", "pty", "--link", str(link))
    try:
        wait_for(lambda: link.exists() and (tmp_path / "site.toml").exists(), "pty", sim)
        site = tmp_path / "beacons.toml"
        site.write_text((tmp_path / "site.toml").read_text() + '\n[[beacons]]\nname = "robot"\nkind = "pfdoa"\n\n'
                        '[[beacons]]\nname = "tag"\nkind = "ibeacon"\nuuid = "f7826da6-4fa2-4e98-8024-bc5b71e0893e"\n'
                        'major = 1\nminor = 2\nperiod_ms = 50\n')
        from pfdoa.gateway.beacons import beacons_config
        from pfdoa.site import load_site

        want = beacons_config(load_site(site).sections).filter_hash
        rc, doc, err = anchors_cmd("filters", "--serial", str(link), "--config", str(site))
        assert rc == 0, err
        assert [(o["anchor"], o["ok"], o["status_hash"]) for o in doc["filter table"]] == [(a, True, want)
                                                                                          for a in (1, 2, 3, 4)]
        rc, doc, err = anchors_cmd("list", "--serial", str(link), "--config", str(site), "--listen", "60")
        assert rc == 0 and all(r["site"]["filters_match"] for r in doc["anchors"]), err
        # Our beacon is still entry 0: its reports keep coming.
        assert all(r["beacons"] in ([], [0]) for r in doc["anchors"])
        rc, doc, err = anchors_cmd("filters", "--serial", str(link), "--default", "--all", "--listen", "8")
        assert rc == 0 and len(doc["filter table"]) == 4, err
        assert {o["status_hash"] for o in doc["filter table"]} == {defs.FILTER_TABLE_DEFAULT_HASH}
    finally:
        stop_sim(sim)


@pytest.mark.parametrize("args, message", [
    (["set", "--stdin", "--anchor", "1"], "--stdin is not bidirectional"),
    (["set", "--serial", "/dev/null", "--anchor", "1", "--alpha", "2"], "--alpha must be in"),
    (["set", "--serial", "/dev/null"], "which anchors?"),
    (["filters", "--serial", "/dev/null", "--all"], "give --config SITE.toml"),
    (["list"], "no transport"),
])
def test_bad_arguments_are_one_line_and_exit_2(args, message):
    rc, _, err = anchors_cmd(*args)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1 and message in lines[0], err


def test_over_can_through_an_slcan_adapter(tmp_path):
    """The same anchors reporting on CAN (SLCAN over a pty): listed (STATUS joined from its
    three CAN parts), configured; FILTER_SET has no CAN mapping and says so."""
    link = tmp_path / "can.tty"
    sim = start_sim(tmp_path, "--transport", "slcan", "--link", str(link))
    try:
        wait_for(lambda: link.exists() and (tmp_path / "site.toml").exists(), "SLCAN pty", sim)
        can = f"slcan:{link}@500000"
        rc, doc, err = anchors_cmd("list", "--can", can, "--config", str(tmp_path / "site.toml"), "--listen", "60")
        assert rc == 0 and sorted(r["anchor"] for r in doc["anchors"]) == [1, 2, 3, 4], err
        assert all(r["status"]["filter_slots"] == defs.BEACON_SLOTS and r["link"] == "can0" for r in doc["anchors"])
        rc, doc, err = anchors_cmd("set", "--can", can, "--anchor", "3", "--offset-db", "-0.75")
        (o,) = doc["configuration"]
        assert rc == 0 and o["ok"] and o["status_hash"] == offset_config(0.75).hash and o["report_checked"], err
        rc, doc, err = anchors_cmd("filters", "--can", can, "--anchor", "3", "--default")
        assert rc == 1 and "FILTER_SET has no CAN mapping" in err
    finally:
        stop_sim(sim)
