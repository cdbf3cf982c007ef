"""Numbers from parsed JSON that came from outside (MQTT payloads, estimate files).

``json.loads`` gives ``bool`` (an ``int`` subclass), ``int`` of any length and ``float``
(including ``inf`` and ``nan`` from ``Infinity``/``NaN``); only finite ``int``/``float``
values within float range are numbers here. ``float()`` of an integer beyond that range
raises ``OverflowError``, which no parser of ours may let escape (fuzz/regressions/espresense).
"""

from __future__ import annotations

import math


def finite_number(v: object) -> float | None:
    """``v`` as a finite float, or None when it is not a finite JSON number."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return None
    try:
        f = float(v)
    except OverflowError:
        return None
    return f if math.isfinite(f) else None
