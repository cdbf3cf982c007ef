"""The study tools in tools/ load against the current package.

Several of them are only run by hand to regenerate a documented figure, so a rename in
pfdoa can break one silently (tools/uncertainty_rules.py imported a helper by its old private
name for a day). Loading each module resolves every name it imports at module level.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

TOOLS = Path(__file__).resolve().parents[2] / "tools"


@pytest.mark.unit
@pytest.mark.parametrize("path", sorted(TOOLS.glob("*.py")), ids=lambda p: p.stem)
def test_tool_loads_and_has_a_main(path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    name = f"_tool_{path.stem}"
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, name, module)  # dataclasses look their module up there
    spec.loader.exec_module(module)
    assert callable(getattr(module, "main", None)), f"{path.name} has no main()"
