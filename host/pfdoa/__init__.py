"""pfdoa: indoor localization from the direction of arrival (DOA) of RSSI in a particle filter."""

__version__ = "0.1.0"
