"""TOML parsing for every module of the tree: ``tomllib`` (Python >= 3.11), else ``tomli``.

``tomli`` is the package ``tomllib`` was taken from (same API, same error type), declared
as a dependency for Python < 3.11 in pyproject.toml. Import ``loads``/``TOMLDecodeError``
from here, never ``tomllib`` itself, so a Python 3.10 install works.
"""

from __future__ import annotations

# mypy checks against Python 3.10 (the oldest supported), whose standard library has no tomllib.
try:
    import tomllib as _impl  # type: ignore[import-not-found,unused-ignore]
except ModuleNotFoundError:  # Python 3.10
    import tomli as _impl  # type: ignore[no-redef,unused-ignore]

loads = _impl.loads
load = _impl.load
TOMLDecodeError = _impl.TOMLDecodeError
IMPLEMENTATION: str = _impl.__name__

__all__ = ["loads", "load", "TOMLDecodeError", "IMPLEMENTATION"]
