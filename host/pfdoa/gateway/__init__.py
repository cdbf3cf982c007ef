"""The host gateway: transports -> stream decoding -> reassembly into anchor sets -> estimator.

Modules: :mod:`.config` (the ``[gateway]`` and ``[output]`` site tables),
:mod:`.transports` (serial, CAN, stdin, capture files), :mod:`.reassembly` (sets by beacon
sequence or by time window, per-anchor health), :mod:`.health` (counters and the periodic
health line), :mod:`.pipeline` (decode -> reassemble -> estimate -> output).
"""
