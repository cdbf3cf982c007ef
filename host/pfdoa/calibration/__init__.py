"""Calibration: the radio model fitted to readings.

:mod:`.calibrate` fits it to walks with ground truth (``pfdoa calibrate TRACE``, with the
radio map of its residuals), :mod:`.peercal` to the anchors' readings of each other. Above
the estimators and the readings (it groups them as the gateway does, :mod:`pfdoa.readings`),
below the gateway (whose live peer calibration uses :mod:`.peercal`) and the evaluation.
"""
