"""Loading a script of tools/ as a module in a test (the converters are scripts, not a package)."""

from __future__ import annotations

import contextlib
import importlib.util
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

TOOLS = Path(__file__).resolve().parents[1] / "tools"


@contextlib.contextmanager
def tool_module(name: str) -> Iterator[ModuleType]:
    """``tools/<name>.py`` imported as ``_<name>``, registered in sys.modules while in use
    (dataclasses look their module up there)."""
    spec = importlib.util.spec_from_file_location(f"_{name}", TOOLS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[f"_{name}"] = module
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.modules.pop(f"_{name}", None)
