"""pfdoasim: software-in-the-loop simulator for pfdoa (``pfdoa sim``; docs/simulator.md).

Modules: :mod:`~pfdoasim.trajectories` (paper paths, waypoints, walks),
:mod:`~pfdoasim.channel` (radio channel on top of :mod:`pfdoa.radio`),
:mod:`~pfdoasim.scenario`, :mod:`~pfdoasim.backends` (anchor cores, one module per
backend behind a registry: the real firmware), :mod:`~pfdoasim.firmware` (where the firmware
tree is), :mod:`~pfdoasim.faults`, :mod:`~pfdoasim.transports`,
:mod:`~pfdoasim.runner` (the beacon loop), :mod:`~pfdoasim.launch` (run options, the
gateway process), :mod:`~pfdoasim.score`, :mod:`~pfdoasim.harness` and
:mod:`~pfdoasim.qemu_harness` (gateway runs in virtual or real time, figures),
:mod:`~pfdoasim.command` (``pfdoa sim``, registered through the ``pfdoa.commands`` entry
point group). The paper's paths and the odometry noise model are :mod:`pfdoa.paths` and
:mod:`pfdoa.odometry`: dependencies run one way, this package imports :mod:`pfdoa`, never
the reverse.
"""
