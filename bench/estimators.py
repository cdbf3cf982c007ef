"""Estimator step time: median ms per ``step`` on realistic simulated observations.

Observations come from the simulator's radio model (:class:`pfdoasim.channel.Channel`, the
``demo`` scenario: 6 x 6 m room, 4 corner anchors, 2 dB noise, 1 dB shadowing, 5 %
multipath bursts, 1 dB quantisation, BLE readings on 3 channels averaged per anchor as the
anchor firmware folds them), one per beacon at 10 Hz along the scenario's seeded walk.
No odometry (the estimators' own motion model runs). Each configuration gets a fresh
estimator with a fixed seed; the first ``warmup`` steps are not timed. pf-doa's N = 200
step is timed against a plain bootstrap particle filter (bench/plain_pf.py) in alternating
rounds of the same observations.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from bench.plain_pf import PlainParticleFilter
from bench.stats import summary
from pfdoa.estimators import Observation, make_estimator
from pfdoa.estimators.markov import MarkovGrid
from pfdoa.radio import PathLoss

PARTICLES = (200, 1000, 5000, 20000)
MARKOV_RESOLUTIONS = (0.2, 0.1, 0.05)  # metres; 0.1 is the estimator's default
SCENARIO = "demo"
SEED = 1
PLAIN = "plain bootstrap PF"  # bench/plain_pf.py: the floor pf-doa's step is measured against


def observations(count: int, seed: int = SEED):
    """(site, [Observation]) for ``count`` beacons of the demo scenario."""
    from pfdoasim.channel import Channel
    from pfdoasim.scenario import build

    sc = build(SCENARIO, seed=seed, duration_s=count / 10.0 + 1.0)
    site = sc.site
    ch = Channel(site.positions, PathLoss.from_site(site), site.offsets, sc.channel, np.random.default_rng(seed))
    chans = sc.channels
    out = []
    for k in range(count):
        t = k / sc.beacon_hz
        x, y, _ = sc.pose_at(t)
        r, _ = ch.sample(np.array([x, y]), chans)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all channels missed: NaN
            rssi = np.nanmean(r, axis=1)
        out.append(Observation(t, rssi))
    return site, out


def with_radio_map(site, seed: int = SEED):
    """``site`` with a ``[radio_map]`` over its anchors' box (0.25 m cells, residuals of 3 dB
    1-sigma, trust 1): what a step costs with a map, whatever the map holds."""
    import dataclasses

    from pfdoa.radiomap import RadioMap

    rng = np.random.default_rng(seed)
    lo, hi = site.positions.min(axis=0), site.positions.max(axis=0)
    gx, gy = np.meshgrid(np.arange(lo[0] + 0.125, hi[0], 0.25), np.arange(lo[1] + 0.125, hi[1], 0.25), indexing="ij")
    n, k = len(site.anchors), gx.size
    rmap = RadioMap(site.anchor_ids, gx.ravel(), gy.ravel(), rng.normal(0.0, 3.0, (n, k)), np.ones((n, k)), 1.0)
    return dataclasses.replace(site, sections={**site.sections, "radio_map": rmap.to_section()})


def time_steps(est, obs, warmup: int) -> list[float]:
    times = []
    clock = time.perf_counter
    for i, o in enumerate(obs):
        t0 = clock()
        est.step(o)
        dt = clock() - t0
        if i >= warmup:
            times.append(dt)
    return times


def interleaved(make_a, make_b, obs, warmup: int, rounds: int) -> tuple[list[float], list[float]]:
    """Step times of two filters over the same observations, fresh filters each round, their
    steps alternating (which goes first alternating too), so that both meet the same load on
    a shared machine (the ratio of their medians is the figure). Whole rounds in turn let a
    burst of load fall on one filter's steps: 1.152 in one run of three that read 0.978 and
    0.962, where alternated steps read 0.94-0.97."""
    a: list[float] = []
    b: list[float] = []
    clock = time.perf_counter
    for _ in range(rounds):
        fa, fb = make_a(), make_b()
        for i, o in enumerate(obs):
            a_first = i % 2 == 0
            first, second = (fa, fb) if a_first else (fb, fa)
            t0 = clock()
            first.step(o)
            t1 = clock()
            second.step(o)
            t2 = clock()
            if i >= warmup:
                d_first, d_second = t1 - t0, t2 - t1
                a.append(d_first if a_first else d_second)
                b.append(d_second if a_first else d_first)
    return a, b


class _Plain:
    """The plain filter behind the estimators' ``step(observation)``."""

    def __init__(self, site, particles: int) -> None:
        self.pf = PlainParticleFilter(site, particles, rng=np.random.default_rng(SEED))

    def step(self, o):
        return self.pf.step(o.t, o.rssi)


def run(quick: bool = False) -> dict:
    """{method: {key: {median, p10, p90, n}}} (ms); bench.run keeps the medians as ``pf_step_ms``,
    and ``PLAIN`` beside pf-doa's N = 200 step, timed in alternating rounds with it."""
    warmup = 3 if quick else 20
    steps = {200: 400, 1000: 300, 5000: 150, 20000: 60}
    site, obs = observations(warmup + max(steps.values()))
    res: dict = {}
    for method in ("pf-doa", "pf-doa-paper"):
        res[method] = {}
        for n in PARTICLES:
            if method == "pf-doa" and n == 200:
                continue  # below, against the plain filter
            k = 5 if quick else steps[n]
            est = make_estimator(method, site, rng=np.random.default_rng(SEED), particles=n)
            res[method][str(n)] = summary(time_steps(est, obs[:warmup + k], warmup))
    k = 5 if quick else steps[200]
    ours, plain = interleaved(lambda: make_estimator("pf-doa", site, rng=np.random.default_rng(SEED), particles=200),
                              lambda: _Plain(site, 200), obs[:warmup + k], warmup, 1 if quick else 5)
    res["pf-doa"] = {"200": summary(ours), **res["pf-doa"]}
    res[PLAIN] = {"200": summary(plain)}
    # The same N = 200 step with a radio map (pfdoa.radiomap; pfdoa calibrate writes one where
    # the calibration trace supports it): its cost is the lookup per particle.
    mapped = with_radio_map(site)
    res["pf-doa (radio map)"] = {"200": summary(time_steps(
        make_estimator("pf-doa", mapped, rng=np.random.default_rng(SEED), particles=200), obs[:warmup + k], warmup))}
    # ... and without leaps (leap_rate 0): what the default's leaps cost.
    res["pf-doa (no leaps)"] = {"200": summary(time_steps(
        make_estimator("pf-doa", site, rng=np.random.default_rng(SEED), particles=200, leap_rate=0.0),
        obs[:warmup + k], warmup))}
    res["markov"] = {}
    for resolution in MARKOV_RESOLUTIONS:
        k = 5 if quick else 100
        est = make_estimator("markov", site, resolution=resolution)
        assert isinstance(est, MarkovGrid)
        cells = int(np.prod(est.shape))
        s = summary(time_steps(est, obs[:warmup + k], warmup))
        s["cells"] = cells
        res["markov"][str(resolution)] = s
    return res
