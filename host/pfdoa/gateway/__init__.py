"""The host gateway: transports -> stream decoding -> anchor clocks -> reassembly into anchor sets -> estimator.

Modules: :mod:`.config` (the ``[gateway]`` and ``[output]`` site tables),
:mod:`.transports` (the inputs' base class and items), :mod:`.inputs` (one module per kind of
input, their registry and spec syntax: serial, CAN, stdin, capture files, MQTT), :mod:`.decoding`
(``Gateway``: decode, map ticks to event times, reassemble), :mod:`.anchorclock` (the
per-anchor clock model), :mod:`.reassembly` (sets by beacon sequence or by time window,
per-anchor health), :mod:`.localizer` (sets -> estimator with the odometry over each
interval -> output), :mod:`.odomsource` (live odometry, odometry files), :mod:`.runner`
(reader threads, the timer rule, capture, health), :mod:`.health` (counters and the
periodic health line), :mod:`.setup` (settings and the one pipeline builder).
"""
