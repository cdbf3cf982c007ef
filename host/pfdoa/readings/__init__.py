"""Anchor readings and their grouping into anchor sets: the gateway's lowest floor.

:mod:`.reassembly` (``Reading``, ``AnchorSet``, the groupers by beacon sequence or by time
window, per-anchor health) and :mod:`.config` (the site's ``[gateway]`` table, which holds
the groupers' timeouts, and ``[output]``). Below the gateway, so that calibration and the
evaluation group readings as the live gateway does without importing it.
"""
