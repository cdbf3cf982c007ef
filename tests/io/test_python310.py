"""Python 3.10 support (requires-python >= 3.10; Ubuntu 22.04 robots run 3.10).

Debian bookworm ships 3.11 only, so a real 3.10 run
(tests/io/test_packaging.py, the wheel in a 3.10 virtualenv) happens only where a 3.10 interpreter
is found. These run everywhere, on the running interpreter: the TOML shim with ``tomllib`` made
unimportable (the state of a 3.10 install, where ``tomli`` is installed by the environment
marker), and a static scan of the tree for syntax and standard-library names that 3.10 lacks.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

from pfdoa import _toml

REPO = Path(__file__).resolve().parents[2]
SOURCES = sorted(p for d in ("host", "sim", "tests", "tools", "bench", "fuzz") for p in (REPO / d).rglob("*.py"))

# Run as a fresh interpreter: tomllib cannot be imported (as on 3.10); then the real CLI
# prints its help and a real site file loads, through tomli.
WITHOUT_TOMLLIB = r"""
import importlib.abc, sys
class NoTomllib(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "tomllib" or name.startswith("tomllib."):
            raise ModuleNotFoundError("No module named 'tomllib'", name=name)
        return None
sys.meta_path.insert(0, NoTomllib())
sys.modules.pop("tomllib", None)
try:
    import tomllib
except ModuleNotFoundError:
    pass
else:
    raise SystemExit("tomllib still importable")

from pfdoa import cli
from pfdoa import _toml
from pfdoa.site import load_site
try:
    cli.main(["--help"])
except SystemExit as exc:
    assert exc.code == 0, exc.code
for command in ("calibrate", "replay", "gateway"):
    try:
        cli.main([command, "--help"])
    except SystemExit as exc:
        assert exc.code == 0, (command, exc.code)
site = load_site(sys.argv[1])
print("IMPL", _toml.IMPLEMENTATION, "ANCHORS", len(site.anchors), "TOMLLIB", "tomllib" in sys.modules)
"""


def test_cli_help_and_site_loading_work_without_tomllib(tmp_path):
    site = REPO / "host" / "pfdoa" / "data" / "herolab_wifi_robot" / "site.toml"
    r = subprocess.run([sys.executable, "-c", WITHOUT_TOMLLIB, str(site)], capture_output=True, text=True,
                       timeout=120, cwd=tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "usage: pfdoa" in r.stdout
    assert r.stdout.strip().splitlines()[-1] == "IMPL tomli ANCHORS 4 TOMLLIB False"


def test_bad_toml_is_the_same_error_type_through_the_shim():
    with pytest.raises(_toml.TOMLDecodeError):
        _toml.loads("[radio\n")
    assert _toml.loads("a = 1\n") == {"a": 1}


def test_every_toml_import_goes_through_the_shim():
    offenders = []
    for p in SOURCES:
        if p == REPO / "host" / "pfdoa" / "_toml.py":
            continue
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"), str(p))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            if any(n.split(".")[0] in ("tomllib", "tomli") for n in names):
                offenders.append(f"{p.relative_to(REPO)}:{node.lineno}")
    assert offenders == []


def test_pyproject_declares_tomli_for_python_below_3_11():
    meta = _toml.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert meta["requires-python"] == ">=3.10"
    markers = [d for d in meta["dependencies"] if d.startswith("tomli")]
    assert len(markers) == 1 and re.search(r";\s*python_version\s*<\s*['\"]3\.11['\"]", markers[0]), markers


# Names added to the standard library after 3.10 (what a 3.10 interpreter would fail on).
NEWER_THAN_310 = re.compile(
    r"\b(typing\.(Self|Never|LiteralString|assert_never|reveal_type|dataclass_transform|NotRequired|Required|TypeVarTuple|Unpack)"
    r"|StrEnum|ReprEnum|datetime\.UTC|from datetime import UTC|asyncio\.(TaskGroup|timeout|Runner)"
    r"|ExceptionGroup|contextlib\.chdir|hashlib\.file_digest|math\.(cbrt|exp2)|itertools\.batched"
    r"|Path\.walk|\.walk\(\)|typing\.override|@override)\b"
)


@pytest.mark.parametrize("path", [p for p in SOURCES if p.parts[len(REPO.parts)] in ("host", "sim")],
                         ids=lambda p: str(p.relative_to(REPO)))
def test_package_source_is_python_310(path):
    text = path.read_text(encoding="utf-8")
    ast.parse(text, str(path), feature_version=(3, 10))  # 3.11+ syntax (except*, ...) fails here
    hits = [f"{i}: {line.strip()}" for i, line in enumerate(text.splitlines(), 1) if NEWER_THAN_310.search(line)]
    assert hits == []
