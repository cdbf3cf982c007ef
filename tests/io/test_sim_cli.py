import json
import subprocess
import sys

import numpy as np
import pytest

from pfdoa import _toml as tomllib
from pfdoa.protocol.defs import ANCHOR_ID_MAX
from pfdoa.site import parse_site
from pfdoasim.harness import gateway_site_toml
from pfdoasim.scenario import build
from pfdoasim.score import read_estimates, score, unwrap_seq


def pfdoa(*args, timeout=60):
    return subprocess.run([sys.executable, "-m", "pfdoa", *args], capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize("args, message", [
    (["--faults", "loss=3"], "loss"),
    (["--faults", "explode=1"], "unknown fault"),
    (["--scenario", "nowhere"], "unknown scenario"),
    (["--scenario", "walk"], "needs a site"),
    (["--speed", "-1"], "--speed"),
    (["--gateway", "--realtime", "--speed", "0"], "finite --speed"),
    (["--realtime", "--transport", "timed"], "no real-time port"),
    (["--faults", "jitter=-1"], "jitter"),
    (["--faults", "skew=1"], "ANCHOR@PPM"),
    (["--config", "/nonexistent/site.toml"], "cannot read"),
    (["--multipath", "0.1:x"], "--multipath"),
    (["--beacon-hz", "0"], "--beacon-hz"),
    (["--transport", "can-virtual"], "add --gateway"),
    (["--calibrate", "2"], "add --gateway"),
    (["--gateway", "--calibrate", "1", "--scenario", "espresense-6x4"], "fixed track"),
    (["--gateway", "--calibrate", "21"], "between 1 and 20"),
    (["--gateway", "--calibrate", "-1"], "between 1 and 20"),
])
def test_user_errors_are_one_line_and_exit_2(args, message):
    base = [] if "--transport" in args else ["--transport", "stdout"]
    r = pfdoa("sim", "--anchor-backend", "py-mean", "--duration", "1", *base, *args)
    assert r.returncode == 2
    assert message in r.stderr and "Traceback" not in r.stderr


def test_a_site_whose_anchor_ids_our_frames_cannot_carry_is_refused(tmp_path):
    """The simulator's anchors run our firmware: a site with a dataset's ids (above 126) is one
    line naming the id, exit 2."""
    site = tmp_path / "big.toml"
    site.write_text("[radio]\nrssi_at_1m_dbm = -45.0\npath_loss_exponent = 2.0\n" + "".join(
        f"[[anchors]]\nid = {a}\nx = {x}\ny = {y}\n" for a, (x, y) in zip((1, 6501, 3), ((0, 0), (5, 0), (0, 5)))))
    r = pfdoa("sim", "--anchor-backend", "py-mean", "--duration", "1", "--transport", "stdout", "--config", str(site))
    assert r.returncode == 2
    assert r.stderr.strip() == (f"pfdoa: error: {site}: anchors[1].id: 6501 cannot come from the simulator's anchors: "
                                f"our frames carry anchor ids 0..{ANCHOR_ID_MAX} (larger ids are for recorded traces "
                                "and ESPresense rooms)")


def test_stdout_transport_writes_frames_and_the_ground_truth(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pfdoa", "-q", "sim", "--anchor-backend", "c", "--transport", "stdout",
                        "--duration", "2", "--speed", "0", "--seed", "7", "--out-dir", str(tmp_path)],
                       capture_output=True, timeout=60)
    assert r.returncode == 0, r.stderr
    frames = [f for f in r.stdout.split(b"\x00") if f]
    assert len(frames) >= 4 * 21  # a report per anchor and beacon, plus STATUS frames
    head = (tmp_path / "trace.csv").read_text().splitlines()[0]
    assert head == "t,anchor,rssi_dbm,gt_x,gt_y,seq"
    assert (tmp_path / "trace.odom.csv").read_text().startswith("t,dx,dy,dtheta\n")
    summary = json.loads((tmp_path / "trace.summary.json").read_text())
    assert summary["beacons"] == 21 and summary["faults"]["total"]["reports"] == 84
    # The same seed gives the same bytes.
    r2 = subprocess.run([sys.executable, "-m", "pfdoa", "-q", "sim", "--transport", "stdout", "--duration", "2",
                         "--speed", "0", "--seed", "7", "--out-dir", str(tmp_path / "again")], capture_output=True, timeout=60)
    assert r2.stdout == r.stdout


def test_gateway_site_file_scales_time_to_the_speed_up():
    sc = build("demo", seed=1, duration_s=5)
    slow = tomllib.loads(gateway_site_toml(sc, 1.0))
    fast = tomllib.loads(gateway_site_toml(sc, 10.0))
    parse_site(fast, "<test>")
    assert fast["gateway"]["health_interval_s"] == pytest.approx(slow["gateway"]["health_interval_s"] / 10)
    assert fast["gateway"]["stale_after_s"] < slow["gateway"]["stale_after_s"]
    huge = tomllib.loads(gateway_site_toml(sc, 1000.0))["gateway"]
    assert huge["set_timeout_s"] >= 0.1 and huge["stale_after_s"] >= 0.25  # a scheduler's stall is not a loss
    assert fast["estimator"]["speed"] > 0
    assert "speed" not in slow.get("estimator", {})  # at 1x the estimator keeps its own default


def test_score_matches_by_sequence_across_the_16_bit_wrap(tmp_path):
    assert list(unwrap_seq(np.array([65534, 65535, 0, 2, 1, 3]))) == [65534, 65535, 65536, 65538, 65537, 65539]
    # Truth: beacon k at x = k. Estimates for beacons 65530.. with seq wrapping, one lost, one late.
    k = np.arange(65520, 65550)
    truth_x = np.arange(65550, dtype=float)
    truth_y = np.zeros(65550)
    lines = []
    for kk in [*k[:5], *k[6:10], k[5], *k[10:]]:
        lines.append(json.dumps({"t": 0, "x": float(kk) + 0.3, "y": 0.4, "seq": int(kk % 65536), "stale": []}))
    lines.append("not json")
    lines.append(json.dumps({"x": None, "y": 1, "seq": 3}))
    p = tmp_path / "est.jsonl"
    p.write_text("\n".join(lines) + "\n")
    est = read_estimates(p)
    assert est.skipped_lines == 2
    s = score(est, truth_x, truth_y, truth_seq0=0)
    assert s.n == 30 and np.allclose(s.errors, 0.5)
    assert s.median == pytest.approx(0.5) and s.p95 == pytest.approx(0.5)


def test_score_reports_how_often_the_truth_lies_within_r95_and_cov(tmp_path):
    """Each scored estimate's error against its own r95 and its covariance's 95 % ellipse
    (squared Mahalanobis distance <= 5.991); lines without one are left out of that share."""
    lines = [
        {"seq": 0, "x": 0.5, "y": 0.0, "r95": 1.0, "cov": [1.0, 0.0, 1.0]},
        {"seq": 1, "x": 1.5, "y": 0.0, "r95": 0.4, "cov": [0.01, 0.0, 0.01]},
        {"seq": 2, "x": 2.5, "y": 0.0, "r95": 1.0},
        {"seq": 3, "x": 3.5, "y": 0.0, "cov": [1.0, 0.9, 1.0]},
    ]
    p = tmp_path / "est.jsonl"
    p.write_text("".join(json.dumps(d) + "\n" for d in lines))
    s = score(read_estimates(p), np.arange(4.0), np.zeros(4))
    assert s.n == 4 and s.in_r95 == pytest.approx(2 / 3) and s.in_cov == pytest.approx(2 / 3)
    assert s.as_dict()["in_r95"] == pytest.approx(0.6667, abs=1e-4)
    bare = tmp_path / "bare.jsonl"
    bare.write_text("".join(json.dumps({k: d[k] for k in ("seq", "x", "y")}) + "\n" for d in lines))
    s = score(read_estimates(bare), np.arange(4.0), np.zeros(4))
    assert s.in_r95 is None and s.in_cov is None and "in_r95" not in s.as_dict()


def test_estimate_lines_with_numbers_beyond_float_range_are_skipped_or_nan():
    """`pfdoa sim --score FILE` reads a file the user names: a JSON integer beyond float range
    (float() raises OverflowError) is not a number, like a string or a bool."""
    from pfdoasim.score import estimates_from_lines

    big = "1" + "0" * 400
    est = estimates_from_lines([f'{{"seq": 1, "x": {big}, "y": 0}}', '{"seq": 2, "x": "1.5", "y": 0}',
                                f'{{"seq": 3, "x": 1.0, "y": 0.0, "r95": {big}, "cov": [{big}, 0, 1]}}'])
    assert est.skipped_lines == 2 and est.seq.tolist() == [3]
    assert np.isnan(est.r95[0]) and np.isnan(est.cov[0, 0]) and est.cov[0, 2] == 1.0
    # the time and the anchor lists likewise: not a number, not a list of ids -> none
    odd = [f'{{"seq": 4, "x": 0, "y": 0, "t": {big}, "stale": 5, "missing": "ab", "anchors": [1, true, 2]}}']
    est = estimates_from_lines(odd)
    assert est.seq.tolist() == [4] and np.isnan(est.t[0])
    assert est.stale == [()] and est.missing == [()] and est.anchors == [(1, 2)]
    assert estimates_from_lines(odd, by_time=True).skipped_lines == 1


def test_score_reports_the_lost_share_of_the_scored_estimates():
    """The lost flag over the scored estimates (after the start-up skip, within the truth);
    lines without the flag are left out; records made in process score as the file would."""
    from pfdoa.output import Record, record_values
    from pfdoasim.score import estimates_from_lines

    lines = [json.dumps({"seq": k, "x": float(k), "y": 0.0, "lost": flag})
             for k, flag in enumerate([True, True, False, True, None, False, "yes", True])]
    est = estimates_from_lines(lines)
    # skip the first two beacons; beacon 7 lies beyond the truth (7 beacons)
    s = score(est, np.arange(7.0), np.zeros(7), skip_s=2.0, beacon_hz=1.0)
    assert s.n == 5 and s.lost == pytest.approx(1 / 3)  # k 2..6: False, True, (none), False, (not a bool)
    assert score(estimates_from_lines(json.dumps({"seq": 0, "x": 0.0, "y": 0.0}) for _ in range(1)),
                 np.zeros(1), np.zeros(1)).lost is None
    rec = Record(t=1.0, x=0.5, y=0.25, sigma=0.1, doa=None, seq=3, anchors=(1, 2, 3), missing=(), stale=(),
                 rebooted=(), lost=True)
    one = estimates_from_lines([json.dumps(record_values(rec))])
    assert one.seq.tolist() == [3] and one.x.tolist() == [0.5] and one.lost.tolist() == [1.0]


def test_overrides_reach_the_radio(tmp_path):
    r = subprocess.run([sys.executable, "-m", "pfdoa", "-q", "sim", "--transport", "stdout", "--duration", "3",
                        "--speed", "0", "--beacon-hz", "4", "--radio", "zigbee", "--multipath", "0.5:10",
                        "--out-dir", str(tmp_path)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, timeout=60)
    assert r.returncode == 0, r.stderr
    d = json.loads((tmp_path / "trace.summary.json").read_text())
    assert d["beacons"] == 13 and d["radio"]["kind"] == "zigbee" and d["radio"]["channels"] == [15]
    assert d["channel"]["multipath_db"] == 10.0 and 0.2 < d["radio"]["multipath"] / d["radio"]["readings"] < 0.8
