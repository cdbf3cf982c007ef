"""Many beacons: 20 beacons x 8 ESPresense-style anchors x 10 readings/s, one gateway on one core.

    python -m bench.fleet [--quick] [--only offline,live]       # both parts, one JSON object

Two measurements, each in its own process pinned to one CPU (``sched_setaffinity``), so
its memory and CPU time are its own and it has one core:

* **offline** - the gateway path without a network, as fast as it runs: for each
  message ESPresense parsing (:class:`pfdoa.gateway.inputs.espresense.EspresenseParser`) -> the
  gateway's pipeline (:func:`pfdoa.gateway.setup.build_pipeline`: its tracker of named
  beacons, a ``WindowGrouper`` and a pf-doa estimator per beacon, ``Localizer``) -> the
  pose payload the publisher would send
  (:func:`pfdoa.mqtt.publisher.pose_payload`); ``poll`` every 10 ms of simulated time.
  *Latency* is the wall time from taking the reading that completes a set to its
  record (perf_counter); *utilization* is process CPU time per simulated second (the
  share of one core the live load needs). The fleet simulator's first 60 s of messages
  are replayed with shifted times for the long run (the beacons jump back to their start
  once a minute), and the resident set size is sampled every simulated minute: memory
  flatness is its growth after the first minute.
* **live** - the real ``pfdoa gateway --mqtt-input espresense`` process (pinned to one
  CPU) on a real mosquitto in real time: a separate process plays the nodes (it builds and
  serialises every message first, then says when it starts, and publishes each at its time
  with paho from one thread, QoS 0 as ESPresense nodes do; its lag behind the schedule,
  ``node_send_lag_ms``, and its CPU share are reported: one process keeps 1600 messages/s
  on schedule); the gateway subscribes, stamps each message with its receive time (as with
  real nodes, whose messages carry none), tracks, estimates and publishes every pose
  (QoS 1); a subscriber in the benchmark's process receives them. *Latency* is a pose's
  arrival at that subscriber minus its ``t`` (the gateway's receive time of the set's last
  reading): the wait for the window's end, the gateway's reader, runner, tracker, estimator
  and publisher, and the hop back through the broker. ``latency_ms`` counts the poses
  whose last reading came at least one window (0.3 s) before the nodes' last message, i.e.
  windows that closed while messages flowed; ``latency_ms_all`` every pose, including the
  end of the run (``end_of_run_poses``: each beacon's last window, which no later reading
  closes, leaves on the timers once its 0.3 s are up, up to 0.3 s after its last reading:
  that was the whole tail of the live latency, measured with timing probes in the
  gateway process). CPU is the gateway process's (all its threads, paho's
  included; /proc) per wall second; RSS is sampled from /proc every 10 s. The pose
  carries the time the gateway released its set (``stamp``: the reading that closed the
  window, or the timers), so ``after_release_ms`` (arrival - stamp, every pose) is the
  gateway's own delay without the wait for the window's end.

Benchmarks measure; they never fail on a time.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

BEACONS, ANCHORS, RATE_HZ = 20, 8, 10.0
ON_TIME_MS = 100.0  # one reporting period


def _rss_mb() -> float:
    with open("/proc/self/status", encoding="ascii") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return round(int(line.split()[1]) / 1024.0, 2)
    return float("nan")


_ALL_CPUS = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None


def _pin_one_cpu() -> int | None:
    try:
        cpu = max(os.sched_getaffinity(0))
        os.sched_setaffinity(0, {cpu})
        return cpu
    except (AttributeError, OSError):
        return None


def _unpin() -> None:
    """In a child: the CPUs the benchmark started with (the nodes do not share the gateway's core)."""
    if _ALL_CPUS:
        os.sched_setaffinity(0, _ALL_CPUS)


def _pct(v: Sequence[float] | np.ndarray) -> dict:
    a = np.asarray(v, dtype=float) * 1e3
    if not a.size:
        return {"n": 0}
    p50, p90, p99 = np.percentile(a, [50, 90, 99])
    return {"p50": round(float(p50), 3), "p90": round(float(p90), 3), "p99": round(float(p99), 3),
            "max": round(float(a.max()), 3), "n": int(a.size),
            "on_time_share": round(float((a <= ON_TIME_MS).mean()), 5)}


def _pipeline(site, seed: int, method: str, on_record):
    """The gateway's pipeline (pfdoa.gateway.setup.build_pipeline) on the fleet's site, in
    window mode with the fleet's window; every record to ``on_record(beacon, record)``."""
    from dataclasses import replace

    from pfdoa.api import build_pipeline, load_settings
    from pfdoasim.fleet import FLEET_WINDOW_S

    class Records:
        def write(self, rec) -> None:
            on_record(rec.beacon, rec)

        def close(self) -> None:
            pass

    st = load_settings("<bench>", site=replace(site, sections={
        "gateway": {"mode": "window", "window_s": FLEET_WINDOW_S}, "beacons": {"max_beacons": 64}}))
    return build_pipeline(st, method=method, seed=seed, named_beacons=True, writer=Records())


def offline(duration_s: float, base_s: float = 60.0, seed: int = 1, method: str = "pf-doa",
            pin: bool = True) -> dict:
    from pfdoa.api import EspresenseParser, espresense_config, pose_payload
    from pfdoasim.fleet import FleetConfig, FleetScenario

    cpu = _pin_one_cpu() if pin else None
    base_s = min(base_s, duration_s)
    sc = FleetScenario(FleetConfig(n_beacons=BEACONS, n_anchors=ANCHORS, rate_hz=RATE_HZ, duration_s=base_s,
                                   seed=seed, time_field=""))
    msgs = [(m.t, m.topic, m.payload) for m in sc.messages()]
    table = {"espresense": {**sc.espresense_table(), "time_field": ""}}
    parser = EspresenseParser(espresense_config(table, "<bench>", sc.site.anchor_ids, sc.site.radio.rssi_at_1m_dbm))
    reps = max(1, int(round(duration_s / base_s)))
    # Preallocated and written (np.zeros pages would become resident one by one during the
    # run), so the measurement itself does not grow the memory it measures.
    lat = np.full(int(BEACONS * RATE_HZ * reps * base_s * 1.1) + 1000, np.nan)
    n_lat = [0]
    clock = [0.0]
    pc = time.perf_counter

    def on_record(beacon, rec) -> None:
        pose_payload(beacon, rec)
        if n_lat[0] < lat.size:
            lat[n_lat[0]] = pc() - clock[0]
            n_lat[0] += 1

    pipe = _pipeline(sc.site, seed, method, on_record)
    tracker, health = pipe.gateway.named, pipe.health
    parse, push, poll = parser.parse, pipe.gateway.push_beacon, pipe.gateway.poll
    rss = [(0.0, _rss_mb())]
    load0 = round(os.getloadavg()[0], 2)
    next_sample, last_poll, n = 60.0, 0.0, 0
    c0, w0 = time.process_time(), pc()
    for rep in range(reps):
        shift = rep * base_s
        for t, topic, payload in msgs:
            t += shift
            clock[0] = pc()
            push(parse(topic, payload, t))
            n += 1
            if t - last_poll >= 0.01:
                clock[0] = pc()
                poll(t)
                last_poll = t
            if t >= next_sample:
                rss.append((round(t, 1), _rss_mb()))
                next_sample += 60.0
    pipe.gateway.finish()
    cpu_s, wall_s = time.process_time() - c0, pc() - w0
    sim_s = reps * base_s
    after_1min = [r for t, r in rss if t >= 60.0]
    return {
        "cpu": cpu, "load_avg_1min_start_end": [load0, round(os.getloadavg()[0], 2)],
        "beacons": BEACONS, "anchors": ANCHORS, "rate_hz": RATE_HZ, "method": method,
        "simulated_s": sim_s, "readings": n, "records": tracker.counters.records, "estimates": health.estimates,
        "estimator_errors": health.estimator_errors,
        "latency_ms": _pct(lat[:n_lat[0]]),
        "cpu_s": round(cpu_s, 2), "wall_s": round(wall_s, 2),
        "utilization_one_core": round(cpu_s / sim_s, 4),
        "realtime_factor": round(sim_s / wall_s, 1),
        "rss_mb": rss,
        "rss_growth_after_1min_mb": round(after_1min[-1] - after_1min[0], 2) if len(after_1min) > 1 else None,
    }


def nodes_main(url: str, duration_s: float, seed: int, lead_s: float = 0.5) -> int:
    """The nodes' process (see the module doc): build and serialise every message, connect,
    say when sending starts (``{"start_at": ...}`` on stdout), publish each message at
    start_at + its simulated time, then print its send lag and CPU time (the last line).

    It keeps its schedule on one core: no work per message but the ``t`` appended to a
    pre-serialised payload and one ``publish``. The messages are built before the start is
    chosen (building 60 s of them takes seconds: a start fixed in advance fell behind by
    that much and then sent the backlog at once). paho is driven from this thread alone
    (no network thread: ``publish`` writes to the socket itself; ``loop`` is the wait
    between messages), so there is no outbox of ours and no thread hand-off per message;
    QoS 0 as ESPresense nodes publish. The GC is frozen after building, so that no
    collection walks the ~100 000 message objects mid-run."""
    import gc

    import paho.mqtt.client as mqtt

    from pfdoa.api import parse_url
    from pfdoasim.fleet import FleetConfig, FleetScenario

    u = parse_url(url)
    sc = FleetScenario(FleetConfig(n_beacons=BEACONS, n_anchors=ANCHORS, rate_hz=RATE_HZ, duration_s=duration_s,
                                   seed=seed, time_field=""))
    # Each payload is a JSON object: the send time goes in as a last field, "t" (for a
    # reader of the broker; the gateway stamps receive times, time_field is "").
    plan = [(m.t, m.topic, m.payload[:-1] + b',"t":') for m in sc.messages()]
    n = len(plan)
    lag = np.zeros(n)
    connected = threading.Event()
    c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="bench-nodes", protocol=mqtt.MQTTv311)
    c.on_connect = lambda *_a: connected.set()
    c.connect(u.host, u.port, keepalive=60)
    end = time.time() + 10.0
    while not connected.is_set() and time.time() < end:
        c.loop(0.05)
    if not connected.is_set():
        return 1
    gc.collect()
    gc.freeze()
    start_at = time.time() + lead_s
    print(json.dumps({"start_at": start_at}), flush=True)
    now = time.time
    publish, loop = c.publish, c.loop
    c0 = time.process_time()
    for i, (t, topic, head) in enumerate(plan):
        due = start_at + t
        wait = due - now()
        while wait > 0.0:
            loop(wait)  # select() on the socket: the wait, and keepalive/reads on the way
            wait = due - now()
        publish(topic, head + b"%.6f}" % due, qos=0)
        lag[i] = now() - due
    last_sent = now()
    sent_s = last_sent - start_at
    end = now() + 10.0
    while c.want_write() and now() < end:  # what the socket did not take at once
        loop(0.05)
    cpu_s = time.process_time() - c0
    c.disconnect()
    print(json.dumps({"sent": n, "send_lag_ms": _pct(lag), "cpu_per_wall_s": round(cpu_s / max(sent_s, 1e-9), 4),
                      "messages_per_s": round(n / max(sent_s, 1e-9), 1), "last_sent": last_sent}))
    return 0


def _proc_cpu_s(pid: int) -> float:
    """utime + stime of a process (all its threads), seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _proc_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return round(int(line.split()[1]) / 1024.0, 2)
    return float("nan")


def live(duration_s: float, seed: int = 1, method: str = "pf-doa") -> dict:
    """The real ``pfdoa gateway --mqtt-input espresense`` process, pinned to one CPU, on a
    real mosquitto; the nodes' process publishes in real time (receive-time stamps, as with
    real nodes: their messages carry no time)."""
    import signal
    from dataclasses import replace

    from pfdoa.api import ClientConfig, MqttClient, parse_url
    from pfdoa.site import site_to_toml
    from pfdoasim.fleet import FLEET_WINDOW_S, FleetConfig, FleetScenario, Mosquitto, stop_process

    prefix = "pfdoa/bench"
    with tempfile.TemporaryDirectory(prefix="pfdoa-bench-fleet-") as tmp, Mosquitto(Path(tmp)) as broker:
        sc = FleetScenario(FleetConfig(n_beacons=BEACONS, n_anchors=ANCHORS, rate_hz=RATE_HZ, duration_s=1.0, seed=seed))
        site = Path(tmp) / "site.toml"
        site.write_text(site_to_toml(replace(sc.site, sections={
            "gateway": {"mode": "window", "window_s": FLEET_WINDOW_S, "health_interval_s": 0.0},
            "beacons": {"max_beacons": 64},
            "espresense": {**sc.espresense_table(), "time_field": ""},
            "mqtt": {"node_id": "bench"}})))
        # A subscriber in this process: every pose, when it arrives (the gateway's other
        # side, as Home Assistant would see it). A pose's t is the receive time of its set's
        # last reading in the gateway, so arrival - t is receive -> estimate -> broker -> here.
        lock = threading.Lock()
        poses: list[tuple[float, str, float, float]] = []
        health: dict = {}

        def on_pose(_topic: str, payload: bytes, t: float) -> None:
            d = json.loads(payload)
            with lock:
                poses.append((t, d["beacon"], d["t"], d["stamp"]))

        def on_health(_topic: str, payload: bytes, _t: float) -> None:
            with lock:
                health.update(json.loads(payload))

        sub = MqttClient(ClientConfig(parse_url(broker.url(prefix)), client_id="bench-subscriber")).start()
        sub.subscribe(f"{prefix}/+/pose", on_pose, 1)
        sub.subscribe(f"{prefix}/health", on_health, 1)
        if not sub.wait_subscribed(f"{prefix}/+/pose", 10):
            raise RuntimeError(broker.log_tail())
        cpu = max(_ALL_CPUS) if _ALL_CPUS else None
        stats = Path(tmp) / "stats.json"
        err = open(Path(tmp) / "gateway.log", "wb")
        gw = subprocess.Popen([sys.executable, "-m", "pfdoa", "gateway", "--config", str(site), "--mqtt",
                               broker.url(prefix), "--mqtt-input", "espresense", "--method", method, "--seed",
                               str(seed), "--out", os.devnull, "--stats", str(stats)],
                              stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err,
                              preexec_fn=(lambda: os.sched_setaffinity(0, {cpu})) if cpu is not None else None)
        try:
            end = time.time() + 60
            def subscribed() -> bool:
                with lock:
                    return bool(((health.get("inputs") or {}).get("espresense") or {}).get("subscribed"))

            while not subscribed():
                if gw.poll() is not None or time.time() > end:
                    raise RuntimeError(f"the gateway did not subscribe: {(Path(tmp) / 'gateway.log').read_text()[-2000:]}")
                time.sleep(0.05)
            nodes = subprocess.Popen([sys.executable, "-m", "bench.fleet", "--nodes", broker.url("nodes"),
                                      "--duration", str(duration_s), "--seed", str(seed)],
                                     cwd=Path(__file__).resolve().parent.parent, stdout=subprocess.PIPE,
                                     text=True, preexec_fn=_unpin)
            # The nodes say when they start, once their messages are built and they are connected.
            started = nodes.stdout.readline() if nodes.stdout is not None else ""
            if not started.startswith("{"):
                nodes.kill()
                raise RuntimeError(f"the nodes' process did not start ({nodes.wait()}): {started!r}")
            start_at = float(json.loads(started)["start_at"])
            while time.time() < start_at:
                time.sleep(0.01)
            c0, w0, r0 = _proc_cpu_s(gw.pid), time.time(), _proc_rss_mb(gw.pid)
            load0 = round(os.getloadavg()[0], 2)
            rss = []
            next_sample = start_at + 10.0
            while nodes.poll() is None:
                if time.time() >= next_sample:
                    rss.append((round(time.time() - start_at, 1), _proc_rss_mb(gw.pid)))
                    next_sample += 10.0
                time.sleep(0.05)
            out, _ = nodes.communicate(timeout=60)
            time.sleep(1.0)  # the last windows close on the gateway's timers
            cpu_s, wall_s = _proc_cpu_s(gw.pid) - c0, time.time() - w0
            load1 = round(os.getloadavg()[0], 2)
            code = stop_process(gw, signal.SIGINT)
        finally:
            if gw.poll() is None:
                stop_process(gw, signal.SIGKILL)
            err.close()
        if code != 128 + signal.SIGINT:  # stopped by the signal, after its final counters
            raise RuntimeError(f"pfdoa gateway exited with {code}: {(Path(tmp) / 'gateway.log').read_text()[-2000:]}")
        final = json.loads(stats.read_text())
        made = final["mqtt"]["estimates"]
        end = time.time() + 30
        while time.time() < end:
            with lock:
                if len({(b, t) for _a, b, t, _s in poses}) >= made:
                    break
            time.sleep(0.05)
        sub.stop(2)
        with lock:
            first: dict[tuple[str, float], float] = {}
            released: dict[tuple[str, float], float] = {}
            for arrival, b, t, stamp in poses:
                first.setdefault((b, t), arrival)
                released.setdefault((b, t), stamp)
        node_stats = json.loads(out.strip().splitlines()[-1])
        steady_until = node_stats["last_sent"] - FLEET_WINDOW_S
        inp = final.get("inputs", {}).get("mqtt-espresense", {})
        return {
            "path": "pfdoa gateway process (--mqtt-input espresense), pinned to one CPU",
            "cpu": cpu, "load_avg_1min_start_end": [load0, load1],
            "beacons": BEACONS, "anchors": ANCHORS, "rate_hz": RATE_HZ, "method": method,
            "duration_s": duration_s, "sent": node_stats["sent"], "node_send_lag_ms": node_stats["send_lag_ms"],
            "nodes_cpu_per_wall_s": node_stats["cpu_per_wall_s"],
            "received": inp.get("messages"), "input_queue_drops": inp.get("queue_drops"),
            "runner_queue_drops": final["queue_drops"], "rejected": inp.get("rejected"),
            "records": final["named_beacons"]["records"], "estimates": final["estimates"],
            "beacons_tracked": final["named_beacons"]["tracked"],
            # While the nodes send; a window still open when they stop closes on the timers
            # once its time is up, up to window_s after its last reading: the end of the run.
            "latency_ms": _pct([a - t for (_b, t), a in first.items() if t < steady_until]),
            "latency_ms_all": _pct([a - t for (_b, t), a in first.items()]),
            "end_of_run_poses": sum(1 for (_b, t) in first if t >= steady_until),
            # From the gateway's release of the set (its window closed: the pose's stamp) to
            # the subscriber: the gateway's own delay, without the wait for the window's end.
            "after_release_ms": _pct([a - released[k] for k, a in first.items()]),
            "gateway_cpu_per_wall_s": round(cpu_s / wall_s, 4),
            "rss_mb_start": r0, "rss_mb": rss,
            "poses_published": made, "poses_received": len(first),
            "mqtt": {k: final["mqtt"][k] for k in ("delivered", "queue_dropped", "undelivered", "disconnects")},
        }


def markdown(r: dict) -> list[str]:
    """Lines for build/bench.md."""
    lines = [f"## Many beacons ({BEACONS} beacons x {ANCHORS} anchors x {RATE_HZ:g} readings/s, one core)", ""]
    o, lv = r.get("offline"), r.get("live")
    if o:
        la = o["latency_ms"]
        lines.append(f"Offline ({o['simulated_s']:g} simulated s, {o['readings']:,} readings, {o['records']:,} "
                     f"estimates): reading -> estimate p50 {la['p50']} ms, p99 {la['p99']} ms, max {la['max']} ms; "
                     f"{100 * o['utilization_one_core']:.1f} % of one core; RSS growth after the first minute "
                     f"{o['rss_growth_after_1min_mb']} MiB (load {o['load_avg_1min_start_end']}).")
    if lv:
        la = lv["latency_ms"]
        rss = [m for _t, m in lv["rss_mb"]]
        mem = f"RSS {min(rss)}..{max(rss)} MiB at the 10 s samples" if rss else f"RSS {lv['rss_mb_start']} MiB"
        al = lv["latency_ms_all"]
        ar = lv["after_release_ms"]
        lines.append(f"Live, the pfdoa gateway process on mosquitto ({lv['duration_s']:g} s, "
                     f"{lv['received']:,}/{lv['sent']:,} messages, {lv['records']:,} estimates, "
                     f"{lv['poses_received']:,} poses received): receive -> pose at a subscriber, while the nodes "
                     f"sent ({la['n']:,} poses), p50 {la['p50']} ms, p99 {la['p99']} ms, max {la['max']} ms, "
                     f"{100 * la['on_time_share']:.2f} % within {ON_TIME_MS:g} ms; with the "
                     f"{lv['end_of_run_poses']} end-of-run windows, p99 {al['p99']} ms, max {al['max']} ms; "
                     f"window released -> pose at the subscriber, every pose, p50 {ar['p50']} ms, p99 {ar['p99']} ms, "
                     f"max {ar['max']} ms, {100 * ar['on_time_share']:.2f} % within {ON_TIME_MS:g} ms; "
                     f"gateway CPU {100 * lv['gateway_cpu_per_wall_s']:.1f} % of one core; {mem}; "
                     f"nodes' send lag p99 {lv['node_send_lag_ms'].get('p99')} ms, max "
                     f"{lv['node_send_lag_ms'].get('max')} ms ({100 * lv['nodes_cpu_per_wall_s']:.1f} % of a core) "
                     f"(load {lv['load_avg_1min_start_end']}).")
    return lines + [""]


def _sub(args: list[str]) -> dict:
    root = Path(__file__).resolve().parent.parent
    p = subprocess.run([sys.executable, "-m", "bench.fleet", *args], cwd=root, capture_output=True, text=True,
                       check=False)
    if p.returncode != 0:
        raise RuntimeError(f"bench.fleet {' '.join(args)} failed ({p.returncode}): {p.stderr.strip()[-2000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def run(quick: bool = False, only: tuple[str, ...] = ("offline", "live")) -> dict:
    """Both parts, each in its own process (the way ``make bench`` would call it)."""
    out = {}
    if "offline" in only:
        out["offline"] = _sub(["--part", "offline", "--duration", "60" if quick else "900"])
    if "live" in only:
        out["live"] = _sub(["--part", "live", "--duration", "5" if quick else "60"])
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="short runs (seconds): the keys, not the numbers")
    ap.add_argument("--only", default="offline,live")
    ap.add_argument("--part", choices=("offline", "live"), help=argparse.SUPPRESS)
    ap.add_argument("--nodes", metavar="URL", help=argparse.SUPPRESS)
    ap.add_argument("--duration", type=float, default=60.0, help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, default=1, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.nodes:
        return nodes_main(a.nodes, a.duration, a.seed)
    if a.part == "offline":
        print(json.dumps(offline(a.duration, seed=a.seed)))
        return 0
    if a.part == "live":
        print(json.dumps(live(a.duration, seed=a.seed)))
        return 0
    print(json.dumps(run(a.quick, tuple(a.only.split(","))), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
