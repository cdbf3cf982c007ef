"""`pip install .` in a fresh virtualenv, then `pfdoa sim` from another directory, runs (issue 15).

The distribution is built as a user's pip builds it (a wheel from a copy of the source tree,
with setup.py's hook shipping the firmware into ``pfdoasim/_firmware``) and installed into
a new virtualenv; no network: the build runs without isolation on this environment's
setuptools, and the runtime dependencies (numpy, pyserial, python-can) are the ones this
environment has, made visible to the new one by a ``.pth`` line. Then, from an empty
directory with a fresh user cache, ``pfdoa sim ... --gateway`` must find the packaged
firmware (not the checkout), compile the C core into the cache, run the gateway and score.

A gateway-only install is lean (issue 51): the same wheel in a virtualenv of its own, its
dependencies resolved by pip (from pip's cache when it has them), has no matplotlib, and
``pfdoa gateway`` and ``pfdoa replay`` run there; a plot asked for says what to install.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
# What `pip install .` reads from a checkout (setup.py, MANIFEST.in and pyproject.toml name the rest).
SOURCE = ("pyproject.toml", "setup.py", "MANIFEST.in", "LICENSE", "README.md", "host", "sim",
          "firmware/core", "firmware/micropython")

pytestmark = [pytest.mark.io, pytest.mark.slow]


def _run(cmd, **kw) -> subprocess.CompletedProcess:
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, **kw)
    assert r.returncode == 0, f"{cmd}:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> dict:
    tmp = tmp_path_factory.mktemp("pkg")
    src = tmp / "src"
    for rel in SOURCE:
        p = REPO / rel
        if p.is_dir():
            shutil.copytree(p, src / rel, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info", "tests"))
        else:
            (src / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(p, src / rel)
    dist = tmp / "dist"
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(dist), str(src)])
    (wheel,) = dist.glob("pfdoa-*.whl")
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)])
    py = venv / "bin" / "python"
    _run([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "-q", str(wheel)])
    purelib = Path(_run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    # This environment's third-party packages, appended after the new venv's own site-packages.
    (purelib / "_pfdoa_test_deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    work = tmp / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PFDOA_FIRMWARE", "PFDOA_CACHE_DIR")}
    env.update(XDG_CACHE_HOME=str(tmp / "cache"), PATH=f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}")
    return {"wheel": wheel, "venv": venv, "py": py, "work": work, "env": env, "cache": tmp / "cache"}


def test_the_wheel_ships_the_firmware_the_simulator_runs(installed):
    with zipfile.ZipFile(installed["wheel"]) as z:
        names = set(z.namelist())
        entry_points = z.read(next(n for n in names if n.endswith(".dist-info/entry_points.txt"))).decode()
    fw = "pfdoasim/_firmware/"
    for f in ("core/include/pfdoa_anchor.h", "core/include/pfdoa_defs.h", "core/src/anchor.c", "core/src/pfdoa_le.h",
              "micropython/pfdoa_anchor.py", "micropython/pfdoa_defs.py", "LICENSE"):
        assert fw + f in names, f
    assert not any(n.startswith(fw + "ports/") or n.endswith("Makefile") for n in names)
    assert "[pfdoa.commands]" in entry_points and "sim = pfdoasim.command" in entry_points


def test_pfdoa_sim_runs_from_another_directory_on_the_packaged_firmware(installed):
    venv, work, env = installed["venv"], installed["work"], installed["env"]
    where = _run([str(installed["py"]), "-c", "import pfdoasim, pfdoa; from pfdoasim import firmware; "
                  "t = firmware.locate(); print(pfdoasim.__file__, pfdoa.__file__, t.origin, t.checkout)"],
                 cwd=work, env=env).stdout.split()
    assert all(Path(p).is_relative_to(venv) for p in where[:2]), where
    assert where[2:] == ["package", "False"]

    r = _run([str(venv / "bin" / "pfdoa"), "-q", "sim", "--scenario", "demo", "--duration", "5", "--gateway",
              "--json"], cwd=work, env=env)
    (run,) = json.loads(r.stdout)
    s = run["score"]
    # 5 s at 10 beacons/s, scored from 2 s on; the demo's first seconds are within a metre or so.
    assert s["n"] >= 25 and s["coverage"] > 0.9, s
    assert 0 < s["rmse_m"] < 1.5, s
    assert run["gateway"]["frames"] > 0 and not run["gateway"]["errors"], run["gateway"]
    assert (work / "build" / "sim" / "demo" / "gateway.jsonl").exists()
    # The C core was compiled from the packaged sources into the user cache, not found in a checkout.
    assert list(installed["cache"].glob("pfdoa/core-*/libpfdoa_anchor.so"))

    mpy = _run([str(venv / "bin" / "pfdoa"), "-q", "sim", "--scenario", "demo", "--duration", "3",
                "--anchor-backend", "mpy", "--transport", "timed", "--out-dir", "mpy"], cwd=work, env=env)
    assert mpy.stdout.count("\n") > 100  # the timed stream of the MicroPython anchors' frames


def test_what_a_pip_install_cannot_run_says_so_in_one_line(installed):
    r = subprocess.run([str(installed["venv"] / "bin" / "pfdoa"), "sim", "--anchor-backend", "qemu", "--gateway"],
                       capture_output=True, text=True, timeout=120, cwd=installed["work"], env=installed["env"])
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "qemu port" in lines[0] and "PFDOA_FIRMWARE" in lines[0], r.stderr


def test_a_gateway_only_install_runs_gateway_and_replay_without_matplotlib(installed, tmp_path):
    with zipfile.ZipFile(installed["wheel"]) as z:
        meta = z.read(next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))).decode()
    requires = [ln.split(":", 1)[1].strip() for ln in meta.splitlines() if ln.startswith("Requires-Dist:")]
    # matplotlib only with the plots (and test) extras, never for a plain install
    assert sorted(r for r in requires if r.startswith("matplotlib")) == [
        'matplotlib>=3.7; extra == "plots"', 'matplotlib>=3.7; extra == "test"'], requires
    lean = tmp_path / "lean"
    _run([sys.executable, "-m", "venv", "--without-pip", str(lean)])
    py = lean / "bin" / "python"
    pip_env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    _run([sys.executable, "-m", "pip", "--python", str(py), "install", "-q", "--disable-pip-version-check",
          str(installed["wheel"])], env=pip_env)
    env = {**installed["env"], "PATH": f"{lean / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}"}
    work = tmp_path / "work"
    work.mkdir()
    gone = subprocess.run([str(py), "-c", "import matplotlib"], capture_output=True, text=True, cwd=work, env=env)
    assert gone.returncode == 1 and "No module named 'matplotlib'" in gone.stderr
    pfdoa = str(lean / "bin" / "pfdoa")
    ex = REPO / "examples"
    r = _run([pfdoa, "-q", "replay", str(ex / "run.csv"), "--config", str(ex / "site.toml"), "--odom",
              str(ex / "run.odom.csv"), "--seed", "1"], cwd=work, env=env)
    assert len(r.stdout.splitlines()) > 30 and all(json.loads(ln)["x"] is not None for ln in r.stdout.splitlines())
    # A timed stream from this environment's simulator, read by the lean gateway.
    cap = _run([sys.executable, "-m", "pfdoa", "-q", "sim", "--scenario", "demo", "--transport", "timed",
                "--duration", "3", "--seed", "1", "--out-dir", str(tmp_path / "sim")]).stdout
    r = subprocess.run([pfdoa, "-q", "gateway", "--config", str(tmp_path / "sim" / "site.toml"), "--replay-capture",
                        "-", "--seed", "1"], input=cap, capture_output=True, text=True, timeout=300, cwd=work, env=env)
    assert r.returncode == 0 and len(r.stdout.splitlines()) > 20, r.stderr[-2000:]
    for cmd in (["eval", "--plots", "img"], ["sim", "--scenario", "demo", "--gateway", "--plot", "x.png"]):
        r = subprocess.run([pfdoa, *cmd], capture_output=True, text=True, timeout=300, cwd=work, env=env)
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and "pip install 'pfdoa[plots]'" in lines[0], r.stderr


def _python310() -> str | None:
    """A CPython 3.10 to install into: ``PFDOA_PYTHON310``, else ``python3.10`` on PATH, else
    pyenv's (development machines of this project have pyenv's 3.10.13; Debian bookworm's
    own Python is 3.11 only)."""
    import glob

    found = [os.environ.get("PFDOA_PYTHON310", ""), shutil.which("python3.10") or "",
             *sorted(glob.glob(os.path.expanduser("~/.pyenv/versions/3.10*/bin/python3.10")))]
    for exe in found:  # pyenv's shim on PATH exists but exits 127 when 3.10 is not selected: run each
        if exe and os.access(exe, os.X_OK):
            r = subprocess.run([exe, "-c", "import sys; print(sys.version_info[:2] == (3, 10))"],
                               capture_output=True, text=True, timeout=60)
            if r.returncode == 0 and r.stdout.strip() == "True":
                return exe
    return None


PYTHON310 = _python310()


@pytest.mark.skipif(PYTHON310 is None, reason="no CPython 3.10 here (set PFDOA_PYTHON310)")
def test_a_real_python_310_installs_the_wheel_and_runs_the_simulator(installed, tmp_path):
    """requires-python allows 3.10 (Ubuntu 22.04 robots): the same wheel installed into a real
    3.10 virtualenv, its dependencies resolved by pip for 3.10 (tomli among them, as the
    environment marker says), then the CLI and `pfdoa sim --gateway` from another directory."""
    venv = tmp_path / "py310"
    _run([str(PYTHON310), "-m", "venv", str(venv)])
    py = venv / "bin" / "python"
    _run([str(py), "-m", "pip", "install", "-q", "--disable-pip-version-check", str(installed["wheel"])])
    env = {**installed["env"], "PATH": f"{venv / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
           "XDG_CACHE_HOME": str(tmp_path / "cache")}
    shim = _run([str(py), "-c", "import pfdoa._toml as t; print(t.IMPLEMENTATION)"], cwd=installed["work"], env=env)
    assert shim.stdout.strip() == "tomli"  # 3.10 has no tomllib: the declared fallback is what runs
    assert "usage: pfdoa" in _run([str(venv / "bin" / "pfdoa"), "--help"], cwd=installed["work"], env=env).stdout
    r = _run([str(venv / "bin" / "pfdoa"), "-q", "sim", "--scenario", "demo", "--duration", "5", "--gateway",
              "--json", "--out-dir", "py310"], cwd=installed["work"], env=env)
    (run,) = json.loads(r.stdout)
    assert run["score"]["n"] >= 25 and 0 < run["score"]["rmse_m"] < 1.5, run["score"]
    assert run["gateway"]["frames"] > 0 and not run["gateway"]["errors"], run["gateway"]
