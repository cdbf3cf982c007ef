"""Dependencies run one way, the backends sit behind one registry, one locator finds the firmware.

The import graph is read from the source (tests/import_graph.py: every import statement
counts, function-level ones included) and must have no arrow from ``pfdoa`` (host/) to
``pfdoasim`` (sim/) and no cycle among modules. The product's parts (its subpackages and
top-level modules) stand in :data:`LAYERS`: a part imports parts of its own layer or lower
ones, never a higher one, and no two parts import each other, however indirectly. The
simulator, tools, benchmarks and fuzzers use the product through ``pfdoa.api`` and the
modules it names public. The checkers themselves are tested on planted trees, so a rule
that stopped matching would fail here too.
"""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

import pytest

from pfdoa import cli
from pfdoa.errors import InputError
from pfdoasim import backends, command, firmware
from pfdoasim.backends.base import AnchorCore, Backend

import import_graph as ig

pytestmark = pytest.mark.unit


def upward(g: ig.Graph) -> list[str]:
    """Arrows from pfdoa to pfdoasim, as 'file:line: importer -> imported'."""
    return [f"{g.files[m]}:{line}: {m} -> {t}" for m, edges in sorted(g.edges.items())
            if m.split(".")[0] == "pfdoa" for t, line in edges.items() if t.split(".")[0] == "pfdoasim"]


def test_pfdoa_never_imports_pfdoasim():
    g = ig.build()
    assert len([m for m in g.files if m.startswith("pfdoa.")]) > 50  # the whole package was read
    assert upward(g) == []


def test_no_import_cycle_among_our_modules():
    assert ig.cycles(ig.build()) == []


def _tree(root: Path, files: dict[str, str]) -> dict[str, Path]:
    for rel, text in files.items():
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return {"pfdoa": root / "host" / "pfdoa", "pfdoasim": root / "sim" / "pfdoasim"}


def test_the_checker_finds_a_planted_upward_import_and_cycle(tmp_path):
    roots = _tree(tmp_path, {
        "host/pfdoa/__init__.py": "",
        "host/pfdoa/low.py": "def f():\n    from pfdoasim.runner import run  # lazy, still an arrow\n",
        "host/pfdoa/a.py": "from pfdoa import b\n",
        "host/pfdoa/b.py": "import pfdoa.c\n",
        "host/pfdoa/c.py": "from . import a\n",  # relative, closes a -> b -> c -> a
        "host/pfdoa/sub/__init__.py": "from .x import y\n",  # a package importing its own module: no cycle
        "host/pfdoa/sub/x.py": "from pfdoa.sub import helper\ny = 1\n",
        "host/pfdoa/sub/helper.py": "",
        "sim/pfdoasim/__init__.py": "",
        "sim/pfdoasim/runner.py": "from pfdoa.low import f\n",
    })
    g = ig.build(roots)
    assert [u.split(": ", 1)[1] for u in upward(g)] == ["pfdoa.low -> pfdoasim.runner"]
    # a -> b -> c -> a, and the lazy upward arrow closes low -> runner -> low
    assert ig.cycles(g) == [["pfdoa.a", "pfdoa.b", "pfdoa.c"], ["pfdoa.low", "pfdoasim.runner"]]


# -- layers ---------------------------------------------------------------------------------
# The product's parts, low to high (a part is a subpackage or a top-level module of pfdoa;
# "pfdoa" is the package's own __init__, its version). An arrow from a part to a part of a
# higher layer is an error, a function-level (lazy) import as much as one at the top.
LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("base", ("pfdoa", "errors", "_toml", "jsonnum", "paths", "clock", "types", "signals", "outfiles",
              "output", "plotting")),
    ("models", ("protocol", "radio", "doa", "radiomap", "odometry", "frames", "rooms", "beacon_setup", "schema")),
    ("estimators", ("estimators",)),
    ("site and traces", ("site", "trace")),
    ("readings and clients", ("readings", "mqtt", "ros2")),
    ("calibration", ("calibration",)),
    ("gateway", ("gateway",)),
    ("outputs", ("sinks", "anchors")),
    ("evaluation", ("evaluation",)),
    ("commands", ("commands",)),
    ("entry points", ("cli", "api")),
    ("main", ("__main__",)),
)
# Parts that import no other part (the protocol is generated from its spec and stands alone).
SELF_CONTAINED = ("pfdoa", "errors", "types", "protocol", "radio")
OUTSIDE = ("sim", "tools", "bench", "fuzz")  # programs that use the product through pfdoa.api


def part(module: str) -> str | None:
    """The product part of a module (pfdoa.gateway.setup -> gateway); None when not pfdoa's."""
    names = module.split(".")
    if names[0] != "pfdoa":
        return None
    return names[1] if len(names) > 1 else "pfdoa"


def part_arrows(g: ig.Graph) -> dict[tuple[str, str], str]:
    """(importer part, imported part) -> where the first such import is, 'file:line: a -> b'."""
    out: dict[tuple[str, str], str] = {}
    for m in sorted(g.edges):
        a = part(m)
        for t, line in sorted(g.edges[m].items()):
            b = part(t)
            if a is not None and b is not None and a != b and (g.ours(t) or t == "pfdoa"):
                out.setdefault((a, b), f"{g.files[m]}:{line}: {m} -> {t}")
    return out


def layer_errors(g: ig.Graph, layers=LAYERS, self_contained=SELF_CONTAINED) -> list[str]:
    """Parts missing from the table, arrows to a higher layer, arrows out of a self-contained part."""
    level = {p: (i, name) for i, (name, parts) in enumerate(layers) for p in parts}
    out = [f"{g.files[m]}: part {part(m)!r} of {m} has no layer in the table"
           for m in sorted(g.files) if part(m) is not None and part(m) not in level]
    for (a, b), where in part_arrows(g).items():
        if a in level and b in level and level[b][0] > level[a][0]:
            out.append(f"{where}: upward, {a} ({level[a][1]}) imports {b} ({level[b][1]})")
        elif a in self_contained:
            out.append(f"{where}: {a} imports no other part")
    return out


def part_cycles(g: ig.Graph) -> list[list[str]]:
    arrows = part_arrows(g)
    parts = {p for pair in arrows for p in pair}
    pg = ig.Graph(files={p: Path(p) for p in parts}, edges={p: {} for p in parts})
    for a, b in arrows:
        pg.edges[a][b] = 0
    return ig.cycles(pg)


def public(module: str) -> bool:
    from pfdoa.api import PUBLIC

    return module == "pfdoa" or any(module == p or module.startswith(p + ".") for p in PUBLIC if p != "pfdoa")


def api_names_used(repo: Path = ig.REPO, dirs=OUTSIDE) -> set[str]:
    used: set[str] = set()
    for d in dirs:
        for path in (repo / d).rglob("*.py"):
            used |= {a.name for n in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
                     if isinstance(n, ast.ImportFrom) and n.module == "pfdoa.api" for a in n.names}
    return used


def outside_errors(g: ig.Graph, repo: Path = ig.REPO, dirs=OUTSIDE) -> list[str]:
    """Imports of pfdoa modules that are neither pfdoa.api nor public, in the programs of ``dirs``
    (a ``from pfdoa import x`` names the module pfdoa.x when there is one)."""
    out = []
    for d in dirs:
        for path in sorted((repo / d).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
            for base, names, line in ig._imports(tree, "outside." + path.stem, False):
                if base.split(".")[0] != "pfdoa":
                    continue
                targets = [f"{base}.{n}" for n in names if f"{base}.{n}" in g.files] or [base]
                out += [f"{path.relative_to(repo)}:{line}: {t}" for t in targets if not public(t)]
    return out


def test_every_part_stands_in_its_layer_and_imports_only_down():
    g = ig.build()
    assert layer_errors(g) == []
    assert {p for _, parts in LAYERS for p in parts} == {part(m) for m in g.files if part(m)}  # no stale row


def test_no_cycle_between_the_parts():
    assert part_cycles(ig.build()) == []


def test_the_outside_programs_use_the_api_and_the_public_modules_only():
    import pfdoa.api as api

    g = ig.build()
    assert outside_errors(g) == []
    assert all(hasattr(api, n) for n in api.__all__) and len(api.__all__) == len(set(api.__all__))
    assert api_names_used() == set(api.__all__)  # small: a name no outside program uses leaves it
    assert all(any(m == p or m.startswith(p + ".") for m in g.files) for p in api.PUBLIC)
    # the product itself never goes through its api
    assert [m for m, e in g.edges.items() if "pfdoa.api" in e and m.startswith("pfdoa.")] == []


def test_the_layer_checker_fails_on_planted_upward_imports(tmp_path):
    roots = _tree(tmp_path, {
        "host/pfdoa/__init__.py": "",
        "host/pfdoa/errors.py": "",
        "host/pfdoa/site.py": "from pfdoa.gateway.setup import build\n",  # module level, upward
        "host/pfdoa/readings/__init__.py": "",
        "host/pfdoa/readings/reassembly.py": (
            "from pfdoa import errors\n"  # down: fine
            "def make():\n    from pfdoa.calibration import fit  # lazy, still upward\n    return fit\n"),
        "host/pfdoa/calibration/__init__.py": "from pfdoa.readings.reassembly import make\nfit = 1\n",
        "host/pfdoa/gateway/__init__.py": "",
        "host/pfdoa/gateway/setup.py": "from pfdoa.site import x\nbuild = 1\n",
        "host/pfdoa/newpart.py": "",  # no row in the table
        "host/pfdoa/protocol/__init__.py": "from pfdoa import errors\n",
        "sim/pfdoasim/__init__.py": "",
    })
    g = ig.build(roots)
    assert [e.split(": ", 1)[1] for e in layer_errors(g)] == [
        "part 'newpart' of pfdoa.newpart has no layer in the table",
        "pfdoa.protocol -> pfdoa.errors: protocol imports no other part",
        "pfdoa.readings.reassembly -> pfdoa.calibration: upward, readings (readings and clients) imports "
        "calibration (calibration)",  # the lazy one
        "pfdoa.site -> pfdoa.gateway.setup: upward, site (site and traces) imports gateway (gateway)",
    ]
    # each upward import also closes a loop of parts, lazy or not
    assert part_cycles(g) == [["calibration", "readings"], ["gateway", "site"]]


def test_the_outside_checker_fails_on_a_planted_internal_import(tmp_path):
    roots = _tree(tmp_path, {
        "host/pfdoa/__init__.py": "",
        "host/pfdoa/api.py": "",
        "host/pfdoa/site.py": "",
        "host/pfdoa/gateway/__init__.py": "",
        "host/pfdoa/gateway/runner.py": "",
        "host/pfdoa/commands/__init__.py": "",
        "host/pfdoa/commands/_common.py": "",
        "sim/pfdoasim/__init__.py": "",
        "tools/ok.py": "from pfdoa.api import Gateway\nfrom pfdoa import site, __version__\n",
        "tools/bad.py": "def run():\n    from pfdoa.gateway import runner  # lazy\n",
        "bench/bad.py": "from pfdoa.commands._common import check_seed\nimport pfdoa.gateway.runner\n",
    })
    g = ig.build(roots)
    assert outside_errors(g, tmp_path, ("tools", "bench")) == [
        "tools/bad.py:2: pfdoa.gateway.runner",  # lazy
        "bench/bad.py:1: pfdoa.commands._common",
        "bench/bad.py:2: pfdoa.gateway.runner",
    ]


def test_the_shared_records_live_on_the_lowest_floor():
    from pfdoa import types
    from pfdoa.estimators import base

    assert (base.Observation, base.Odometry, base.Estimate) == (types.Observation, types.Odometry, types.Estimate)
    g = ig.build()
    assert [t for t in g.edges["pfdoa.types"] if g.ours(t)] == []
    assert not [t for t in g.edges["pfdoa.odometry"] if t.startswith("pfdoa.estimators")]


# -- backends -------------------------------------------------------------------------------
def test_every_registered_backend_is_one_module_with_its_named_class():
    seen = set()
    for name, (module, cls, summary) in backends.BACKENDS.items():
        b = backends.backend(name)
        assert isinstance(b, Backend) and type(b).__name__ == cls and type(b).__module__ == module
        assert b.name == name and summary
        seen.add(module)
    assert len(seen) == len(backends.BACKENDS) == 4
    with pytest.raises(InputError, match="unknown anchor backend 'nope'"):
        backends.backend("nope")


def test_anchor_backend_choices_come_from_the_registry():
    p = argparse.ArgumentParser()
    command.add_arguments(p)
    (action,) = [a for a in p._actions if a.dest == "anchor_backend"]
    assert tuple(action.choices) == backends.names() and action.default == backends.DEFAULT
    for name, (_, _, summary) in backends.BACKENDS.items():
        assert f"{name}: {summary}" in action.help


@pytest.mark.parametrize("name", ["py-mean", "mpy"])
def test_in_process_backends_make_anchor_cores(name):
    make = backends.anchor_factory(name)
    core = make(1, False, None, 0)
    assert isinstance(core, AnchorCore) and core.anchor_id == 1
    with pytest.raises(InputError, match="own serial ports"):
        backends.anchor_factory("qemu")


# -- the sim command comes from the simulator package ---------------------------------------
def test_sim_is_the_simulators_registered_command():
    mods = dict(cli._command_modules())
    assert mods["sim"] is command
    assert "pfdoa.commands.sim" not in {getattr(m, "__name__", "") for m in mods.values()}


def test_sim_without_the_simulator_says_so_in_one_line(monkeypatch, capsys):
    monkeypatch.setattr(cli.metadata, "entry_points", lambda group: [])
    assert cli.main(["sim", "--scenario", "demo", "--gateway"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["pfdoa: error: pfdoa sim: the simulator (package pfdoasim) is not installed "
                   "(pip install . from a pfdoa checkout)"]


def test_a_broken_registered_command_says_why_and_the_rest_still_work(monkeypatch, capsys):
    from importlib.metadata import EntryPoint

    broken = EntryPoint("sim", "pfdoasim.no_such_module", "pfdoa.commands")
    monkeypatch.setattr(cli.metadata, "entry_points", lambda group: [broken])
    assert cli.main(["sim"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "pfdoasim.no_such_module cannot be imported (ModuleNotFoundError" in line
    with pytest.raises(SystemExit) as exc:
        cli.main(["replay", "--help"])
    assert exc.value.code == 0


# -- the firmware locator -------------------------------------------------------------------
def test_the_checkout_is_found_first():
    t = firmware.locate()
    assert t.origin == "checkout" and t.checkout and t.root == firmware.CHECKOUT
    assert (t.part("core") / "src" / "anchor.c").is_file()
    assert (t.part("qemu port") / "Makefile").is_file()


def test_pfdoa_firmware_names_the_tree_or_fails_in_one_line(tmp_path, monkeypatch):
    monkeypatch.setenv(firmware.ENV_FIRMWARE, str(tmp_path))
    with pytest.raises(InputError, match=r"PFDOA_FIRMWARE=.*not a pfdoa firmware folder"):
        firmware.locate()
    (tmp_path / firmware.MARKER).parent.mkdir(parents=True)
    (tmp_path / firmware.MARKER).write_text("")
    t = firmware.locate()
    assert t.origin == "PFDOA_FIRMWARE" and not t.checkout
    with pytest.raises(InputError, match="micropython"):
        t.part("micropython")


def test_no_firmware_anywhere_is_one_clear_error(tmp_path, monkeypatch):
    monkeypatch.delenv(firmware.ENV_FIRMWARE, raising=False)
    monkeypatch.setattr(firmware, "CHECKOUT", tmp_path / "none")
    monkeypatch.setattr(firmware, "PACKAGED", tmp_path / "none2")
    with pytest.raises(InputError) as exc:
        firmware.locate()
    msg = str(exc.value)
    assert "\n" not in msg and "was not found" in msg and "PFDOA_FIRMWARE" in msg and str(tmp_path / "none") in msg


def test_a_packaged_tree_lacks_the_qemu_port_and_says_what_to_do(tmp_path, monkeypatch):
    monkeypatch.delenv(firmware.ENV_FIRMWARE, raising=False)
    monkeypatch.setattr(firmware, "CHECKOUT", tmp_path / "none")
    monkeypatch.setattr(firmware, "PACKAGED", tmp_path / "_firmware")
    (tmp_path / "_firmware" / firmware.MARKER).parent.mkdir(parents=True)
    (tmp_path / "_firmware" / firmware.MARKER).write_text("")
    t = firmware.locate()
    assert t.origin == "package"
    with pytest.raises(InputError, match="qemu port.*run from a pfdoa checkout"):
        t.part("qemu port")


def test_cache_dir_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("PFDOA_CACHE_DIR", str(tmp_path / "c"))
    assert firmware.cache_dir() == tmp_path / "c"
    monkeypatch.delenv("PFDOA_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
    assert firmware.cache_dir() == tmp_path / "x" / "pfdoa"


def _held(lock: Path) -> bool:
    """Whether another open file holds an exclusive flock on ``lock``."""
    import fcntl

    with open(lock, "a") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        fcntl.flock(fh, fcntl.LOCK_UN)
        return False


@pytest.mark.parametrize("backend", ["c", "qemu"])
def test_a_checkouts_make_runs_under_the_build_lock(backend, tmp_path, monkeypatch):
    # Two simulators or test workers starting at once must not run two makes over one build
    # folder: the second waits on the lock. make itself is replaced; the lock is looked at
    # from a second open file while it "runs".
    import subprocess

    from pfdoasim.backends import c, qemu

    tree = tmp_path / "firmware"
    (tree / firmware.MARKER).parent.mkdir(parents=True)
    (tree / firmware.MARKER).write_text("")
    (tree / "Makefile").write_text("")
    (tree / "ports" / "qemu_mps2").mkdir(parents=True)
    monkeypatch.setenv(firmware.ENV_FIRMWARE, str(tree))
    build = tree / "build" / ("host" if backend == "c" else "qemu_mps2")
    lock = (tree / "build" if backend == "c" else build) / ".lock"
    seen: list[bool] = []

    def fake_make(cmd, **kw):
        seen.append(_held(lock))
        build.mkdir(parents=True, exist_ok=True)
        (build / c.LIB_NAME).write_text("")
        return subprocess.CompletedProcess(cmd, 0, "", "")

    monkeypatch.setattr(subprocess, "run", fake_make)
    monkeypatch.setattr(qemu.shutil, "which", lambda tool: "/usr/bin/" + tool)
    if backend == "c":
        c.build_library()
    else:
        qemu.build_images()
    assert seen == [True]
    assert not _held(lock)  # and let go afterwards
