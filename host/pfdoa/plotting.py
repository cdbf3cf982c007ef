"""matplotlib, for the plots only (``pip install 'pfdoa[plots]'``).

The gateway, replay and the other commands never import it, so a gateway-only install
(``pip install pfdoa``) leaves it out. A command asked for a plot checks first
(:func:`require`), before any work, and says in one line what to install (exit 2).
"""

from __future__ import annotations

import importlib.util

from pfdoa.errors import InputError

PLOTS_EXTRA = "pip install 'pfdoa[plots]'"


def require(option: str) -> None:
    """InputError naming ``option`` when matplotlib is not installed."""
    if importlib.util.find_spec("matplotlib") is None:
        raise InputError(f"{option}: plots need matplotlib, which is not installed ({PLOTS_EXTRA})")


def pyplot(option: str):
    """``matplotlib.pyplot`` on the Agg backend (files, no display); InputError naming
    ``option`` without matplotlib."""
    require(option)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
