"""Anchor-to-anchor links: what every anchor's radio reports of another anchor's own
advertisement (peer readings, protocol/SPEC.md 3.5), through the same channel as the
beacon's readings.

For the link from anchor ``j`` to anchor ``i``::

    reading = A - 10 n log10(d_ij) + rx_i + tx_j   (pfdoa.calibration.peercal.peer_mean_rssi: pfdoa.radio's
                                                    law at the anchors' own 3-D distance)
            + s_ij                                  (the room's shadowing, reciprocal)
            + channel_offset[i, ch] + noise - bursts, rounded, the radio's range
                                                    (Channel.readings, as every beacon reading)

``rx_i`` is the receiver offset the beacon's readings carry too (the scenario's
``true_offsets``); ``tx_j`` the anchor's transmit offset (``true_tx_offsets``), relative to
the beacon's transmitter (0). ``s_ij`` is the shadowing field of :class:`~pfdoasim.channel.Channel`
at each end, symmetrised: ``(S_i(p_j) + S_j(p_i)) / sqrt(2)``, so a wall between two anchors
weakens the link both ways, by as much as the field's sigma. The readings' noise has its own
random stream (``rng``): anchors that advertise leave the beacon's readings as they were.
"""

from __future__ import annotations

import numpy as np

from pfdoa.api import peer_mean_rssi
from pfdoa.radio import PathLoss
from pfdoa.site import Site
from pfdoasim.channel import Channel


class PeerLinks:
    """Every directed link of ``site``'s anchors in ``channel`` (see the module doc)."""

    def __init__(self, channel: Channel, site: Site, rx_offsets: np.ndarray | None, tx_offsets: np.ndarray | None,
                 rng: np.random.Generator) -> None:
        n = len(site.anchors)
        self.channel = channel
        self.rng = rng
        rx = np.zeros(n) if rx_offsets is None else np.asarray(rx_offsets, dtype=float)
        tx = np.zeros(n) if tx_offsets is None else np.asarray(tx_offsets, dtype=float)
        s = channel.shadowing(site.positions)  # s[j, i]: anchor i's field at anchor j
        self.shadowing = (s + s.T) / np.sqrt(2.0)
        np.fill_diagonal(self.shadowing, 0.0)
        # expected[i, j]: what anchor i hears of anchor j's advertisement, noise-free (NaN: itself)
        self.expected = peer_mean_rssi(site, PathLoss.from_site(site), rx, tx) + self.shadowing.T

    def sample(self, transmitter: int, channels: np.ndarray) -> tuple[np.ndarray, dict[str, int]]:
        """Every anchor's readings (n, m) of anchor ``transmitter``'s advertisement on
        ``channels``; the transmitter's own row is NaN (it does not hear itself)."""
        base = self.expected[:, transmitter].copy()
        base[transmitter] = 0.0
        r, counts = self.channel.readings(base, channels, self.rng)
        r[transmitter, :] = np.nan
        return r, counts
