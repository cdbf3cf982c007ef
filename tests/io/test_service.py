"""The gateway as a systemd service (packaging/systemd, docs/robot.md "Running as a service").

``systemd-analyze verify`` (Debian's systemd; no running systemd needed) passes on the unit
with nothing to say; it refuses an ExecStart whose binary is missing, so the test points a
copy of the unit at this environment's ``pfdoa`` (the installed unit names /opt/pfdoa). The
environment file's options are the gateway's own: what systemd makes of ExecStart parses
with ``pfdoa gateway``'s parser, and a gateway run with them writes its positions to
/dev/null and exits 0. Nothing in the unit hides /dev (the serial ports)."""

from __future__ import annotations

import configparser
import json
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from pfdoa.cli import build_parser

pytestmark = pytest.mark.io

REPO = Path(__file__).resolve().parents[2]
UNIT = REPO / "packaging" / "systemd" / "pfdoa-gateway.service"
ENV = REPO / "packaging" / "systemd" / "pfdoa-gateway.env"
INSTALLED = "/opt/pfdoa/bin/pfdoa"


def unit() -> configparser.ConfigParser:
    c = configparser.ConfigParser(interpolation=None, strict=False)
    c.optionxform = str  # keys keep their case
    c.read(UNIT)
    return c


def env() -> dict[str, str]:
    out = {}
    for line in ENV.read_text().splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            k, _, v = line.partition("=")
            out[k.strip()] = v.strip()
    return out


def exec_start_argv() -> list[str]:
    """ExecStart as systemd expands it with the environment file: ${NAME} is one word,
    $NAME is split at whitespace."""
    e = env()
    out = []
    for word in unit()["Service"]["ExecStart"].split():
        if word.startswith("${") and word.endswith("}"):
            out.append(e[word[2:-1]])
        elif word.startswith("$"):
            out += e[word[1:]].split()
        else:
            out.append(word)
    return out


def systemd_analyze() -> str:
    exe = shutil.which("systemd-analyze")
    if exe is None:
        pytest.fail("systemd-analyze is part of the test environment (tools/bootstrap.sh test: Debian systemd)")
    return exe


def test_systemd_analyze_verify_passes_on_the_unit(tmp_path):
    pfdoa = Path(sys.executable).with_name("pfdoa")
    assert pfdoa.exists(), pfdoa
    text = UNIT.read_text()
    assert text.count(INSTALLED) == 1
    copy = tmp_path / UNIT.name
    copy.write_text(text.replace(INSTALLED, str(pfdoa)))
    r = subprocess.run([systemd_analyze(), "verify", "--man=no", str(copy)], capture_output=True, text=True,
                       timeout=120, cwd=tmp_path)
    assert r.returncode == 0 and r.stderr.strip() == "" and r.stdout.strip() == "", r.stderr + r.stdout
    # The check is real: a misspelt value is reported, a missing binary fails.
    (tmp_path / "bad.service").write_text(copy.read_text().replace("RestartSec=5", "RestartSec=five"))
    r = subprocess.run([systemd_analyze(), "verify", "--man=no", str(tmp_path / "bad.service")],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert "Failed to parse sec value, ignoring: five" in r.stderr
    r = subprocess.run([systemd_analyze(), "verify", "--man=no", str(UNIT)], capture_output=True, text=True,
                       timeout=120, cwd=tmp_path)
    assert r.returncode != 0 and INSTALLED in r.stderr


def test_the_unit_runs_the_gateway_as_its_own_user_with_the_serial_group_and_restarts_it():
    s = unit()["Service"]
    assert exec_start_argv()[:2] == [INSTALLED, "gateway"]
    assert (s["User"], s["Group"], s["SupplementaryGroups"]) == ("pfdoa", "pfdoa", "dialout")
    assert s["EnvironmentFile"] == "/etc/pfdoa/gateway.env" and s["StateDirectory"] == "pfdoa"
    assert (s["Restart"], s["RestartPreventExitStatus"]) == ("on-failure", "2")  # exit 2: a bad site file
    assert s["SuccessExitStatus"].split() == ["130", "143"]  # the gateway's status after SIGINT/SIGTERM
    assert s["NoNewPrivileges"] == "yes" and s["ProtectSystem"] == "strict" and s["CapabilityBoundingSet"] == ""
    # /dev as it is: the serial ports stay reachable.
    for hides_devices in ("PrivateDevices", "DevicePolicy", "DeviceAllow", "ProtectClock"):
        assert hides_devices not in s, hides_devices
    assert "AF_CAN" in s["RestrictAddressFamilies"].split()  # socketcan anchors
    assert unit()["Install"]["WantedBy"] == "multi-user.target"


def test_the_environment_file_holds_options_the_gateway_takes(tmp_path):
    argv = exec_start_argv()
    assert argv[2:4] == ["--config", "/etc/pfdoa/site.toml"]
    args = build_parser().parse_args(argv[1:])
    assert args.serial == ["/dev/ttyACM0"] and args.web == "127.0.0.1:8080" and args.out == "/dev/null"
    # Those options, with a recorded stream in place of the serial port and a free web port.
    out = tmp_path / "sim"
    sim = subprocess.run([sys.executable, "-m", "pfdoa", "-q", "sim", "--scenario", "demo", "--transport", "timed",
                          "--duration", "3", "--seed", "1", "--out-dir", str(out)], capture_output=True, text=True,
                         timeout=300, check=True)
    opts = shlex.split(env()["PFDOA_GATEWAY_ARGS"])
    opts[opts.index("--serial"):opts.index("--serial") + 2] = ["--replay-capture", "-"]
    opts[opts.index("--web") + 1] = "127.0.0.1:0"
    r = subprocess.run([sys.executable, "-m", "pfdoa", "gateway", "--config", str(out / "site.toml"), *opts,
                        "--stats", str(tmp_path / "stats.json")], input=sim.stdout, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads((tmp_path / "stats.json").read_text())["estimates"] > 10
