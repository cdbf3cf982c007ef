"""pfdoa: indoor localization from anchors' RSSI with a particle filter after PF-DOA."""

__version__ = "0.1.0"
