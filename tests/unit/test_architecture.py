"""Dependencies run one way, the backends sit behind one registry, one locator finds the firmware.

The import graph is read from the source (tests/import_graph.py: every import statement
counts, function-level ones included) and must have no arrow from ``pfdoa`` (host/) to
``pfdoasim`` (sim/) and no cycle among modules. The checker itself is tested on planted
trees, so a rule that stopped matching would fail here too.
"""

from __future__ import annotations

import argparse
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
