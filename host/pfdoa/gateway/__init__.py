"""The host gateway: transports -> stream decoding -> anchor clocks -> reassembly into anchor sets -> estimator.

The readings, their groupers and the ``[gateway]`` table are :mod:`pfdoa.readings`.
Modules: :mod:`.transports` (the inputs' base class and items), :mod:`.inputs` (one module per kind of
input, their registry and spec syntax: serial, CAN, stdin, capture files, MQTT), :mod:`.decoding`
(``Gateway``: decode, map ticks to event times, reassemble), :mod:`.anchorclock` (the
per-anchor clock model), :mod:`.localizer` (sets -> estimator with the odometry over each
interval -> output), :mod:`.odomsource` (live odometry, odometry files), :mod:`.runner`
(reader threads, the timer rule, capture, health), :mod:`.health` (counters and the
periodic health line), :mod:`.setup` (settings and the one pipeline builder).
"""
