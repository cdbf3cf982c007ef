"""pfdoasim: software-in-the-loop simulator for pfdoa.

Trajectories, a radio channel on top of :mod:`pfdoa.radio`, emulated anchors that run
the real firmware core (through ctypes), transports (pty, CAN) and fault injection.
"""

__all__ = ["trajectories"]
