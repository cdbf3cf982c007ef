"""`make bench` harness: every key present with sane types (tiny --quick run; no timings asserted)."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def quick(tmp_path_factory) -> tuple[dict, str]:
    out = tmp_path_factory.mktemp("bench")
    js, md = out / "bench.json", out / "bench.md"
    proc = subprocess.run([sys.executable, "-m", "bench.run", "--quick", "--out", str(js), "--md", str(md)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(js.read_text()), md.read_text()


def _positive(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


def test_machine_info(quick) -> None:
    m = quick[0]["machine"]
    assert isinstance(m["cpu_count"], int) and m["cpu_count"] >= 1
    assert m["python"].count(".") == 2 and m["numpy"]
    assert quick[0]["quick"] is True and "errors" not in quick[0]


def test_step_times(quick) -> None:
    ps = quick[0]["pf_step_ms"]
    spread = quick[0]["pf_step_ms_spread"]
    for method in ("pf-doa", "pf-doa-paper"):
        assert set(ps[method]) == {"200", "1000", "5000", "20000"}
    assert "0.1" in ps["markov"] and spread["markov"]["0.1"]["cells"] > 100
    assert set(ps["pf-doa (radio map)"]) == {"200"}  # the map's cost beside the same N
    assert set(ps["plain bootstrap PF"]) == {"200"}  # the floor the default's step is measured against
    assert set(ps["pf-doa (no leaps)"]) == {"200"}  # and the leaps' cost, as the default step less them
    for method, by in ps.items():
        for key, median in by.items():
            s = spread[method][key]
            assert _positive(median) and median == s["median"] and s["p10"] <= median <= s["p90"] and s["n"] >= 1


def test_gateway(quick) -> None:
    r = quick[0]
    for path in ("uart", "uart_bulk_4096", "can"):
        g = r["gateway_frames_per_s_detail"][path]
        assert r["gateway_frames_per_s"][path] == g["median"]
        assert isinstance(g["median"], int) and g["min"] <= g["median"] <= g["max"] and g["median"] > 0
        assert _positive(g["cpu_median"]) and g["frames"] > 0
    pd = r["protocol_decode_frames_per_s"]
    assert all(isinstance(pd[k], int) and pd[k] > 0 for k in ("uart_4096", "uart_64", "can"))
    lat = r["latency_ms"]
    assert _positive(lat["p50"]) and lat["p50"] <= lat["p99"] <= lat["max"] and lat["n"] > 0
    assert _positive(lat["wcl"]["p50"])
    assert _positive(r["gateway_peak_rss_mb"])
    run = r["gateway_memory_run"]
    assert run["frames"] == 20_000 and run["sets"] == 5_000 and run["estimates"] == 5_000
    assert run["baseline_rss_mb"] <= run["peak_rss_mb"]


def test_firmware(quick) -> None:
    r = quick[0]
    for cpu in ("cortex-m0plus", "cortex-m4"):
        fw = r["firmware_text_bytes"][cpu]
        assert 0 < fw["budget_core"] < fw["whole_core"]
        assert fw["budget_core"] == sum(fw["objects"][o]["text"] for o in ("crc16", "cobs", "config", "msg", "frame",
                                                                           "filter"))
        assert all(o["code"] + o["rodata"] == o["text"] for o in fw["objects"].values())
    ins = r["firmware_instructions_per_report"]
    # Deterministic counts: an event costs more than its report alone, a report costs something.
    assert _positive(ins["per_report"]) and ins["per_event"] > ins["per_report"]
    assert ins["per_event_silent"] < ins["per_event"] and ins["reports"] == ins["events"][1]


def test_fleet(quick) -> None:
    """The fleet section: the offline tracker run and the live run through the real
    pfdoa gateway process on mosquitto; what they count is exact, no timing asserted."""
    f = quick[0]["fleet"]
    o, lv = f["offline"], f["live"]
    assert o["readings"] == 20 * 8 * 10 * 60 and o["records"] == o["estimates"] == o["latency_ms"]["n"] > 0
    assert lv["path"].startswith("pfdoa gateway process") and lv["received"] == lv["sent"] == 20 * 8 * 10 * 5
    assert lv["input_queue_drops"] == 0 and lv["runner_queue_drops"] == 0 and lv["rejected"] == {}
    assert lv["records"] == lv["estimates"] == lv["poses_published"] == lv["poses_received"] == lv["latency_ms_all"]["n"]
    # The steady part and the end of the run (each beacon's last window or so) split every pose.
    assert lv["latency_ms"]["n"] + lv["end_of_run_poses"] == lv["poses_received"] and lv["latency_ms"]["n"] > 0
    assert lv["end_of_run_poses"] >= 20  # at least each beacon's last window
    assert lv["beacons_tracked"] == 20 and lv["mqtt"]["undelivered"] == 0 and lv["mqtt"]["queue_dropped"] == 0
    la = lv["latency_ms"]
    assert la["p50"] <= la["p99"] <= la["max"] and 0.0 <= la["on_time_share"] <= 1.0
    # A pose's stamp is when its window was released, after its last reading (t): the
    # delay after release is shorter than the latency from the last reading.
    ar, al = lv["after_release_ms"], lv["latency_ms_all"]
    assert ar["n"] == lv["poses_received"] and ar["p50"] < al["p50"] and ar["max"] <= al["max"]
    assert _positive(lv["gateway_cpu_per_wall_s"]) and _positive(lv["rss_mb_start"])
    # The nodes' process: every message's send lag, and its own CPU share.
    assert lv["node_send_lag_ms"]["n"] == lv["sent"] and _positive(lv["nodes_cpu_per_wall_s"])


def test_targets_and_markdown(quick) -> None:
    r, md = quick
    assert set(r["targets"]) == {"pf_step_ms_pf-doa_200", "pf_step_ratio_to_plain_200", "gateway_frames_per_s_uart",
                                 "firmware_core_text_cortex-m4"}
    ratio = r["targets"]["pf_step_ratio_to_plain_200"]["value"]
    assert ratio == round(r["pf_step_ms"]["pf-doa"]["200"] / r["pf_step_ms"]["plain bootstrap PF"]["200"], 3)
    assert all(isinstance(t["met"], bool) for t in r["targets"].values())
    for heading in ("Estimator step", "Gateway throughput", "Set latency", "Gateway memory", "Firmware size",
                    "Firmware instructions", "Targets", "Many beacons"):
        assert f"## {heading}" in md
