"""pfdoasim: software-in-the-loop simulator for pfdoa (``pfdoa sim``; docs/simulator.md).

Modules: :mod:`~pfdoasim.trajectories` (paper paths, waypoints, walks),
:mod:`~pfdoasim.channel` (radio channel on top of :mod:`pfdoa.radio`),
:mod:`~pfdoasim.odometry`, :mod:`~pfdoasim.scenario`, :mod:`~pfdoasim.anchors` /
:mod:`~pfdoasim.ccore` / :mod:`~pfdoasim.mpyanchor` / :mod:`~pfdoasim.qemu` (anchor cores:
the real firmware), :mod:`~pfdoasim.faults`, :mod:`~pfdoasim.transports`,
:mod:`~pfdoasim.runner` (the beacon loop), :mod:`~pfdoasim.launch` (run options, the
gateway process), :mod:`~pfdoasim.score` and :mod:`~pfdoasim.harness` (gateway runs in
virtual or real time, figures).
"""
