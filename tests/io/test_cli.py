"""The `pfdoa` command line as a user meets it: help texts, configuration errors (subprocess)."""

import subprocess
import sys
import textwrap

import pytest

from pfdoa.cli import _command_modules

PY = sys.executable
GOOD = textwrap.dedent(
    """\
    [radio]
    rssi_at_1m_dbm = -45.0
    path_loss_exponent = 2.2
    [[anchors]]
    id = 0
    x = 0.0
    y = 0.0
    [[anchors]]
    id = 1
    x = 0.0
    y = 4.0
    [[anchors]]
    id = 2
    x = 4.0
    y = 0.0
    """
)
TRACE = "t,anchor,rssi_dbm\n0.0,0,-50\n0.0,1,-52\n0.0,2,-55\n1.0,0,-51\n1.0,1,-53\n1.0,2,-54\n"


def pfdoa(*args, **kw):
    return subprocess.run([PY, "-m", "pfdoa", *args], capture_output=True, text=True, timeout=60, **kw)


def test_top_level_help_lists_every_command():
    r = pfdoa("--help")
    assert r.returncode == 0
    for name, mod in _command_modules():
        assert name in r.stdout
        assert mod.HELP.split()[0] in r.stdout


@pytest.mark.parametrize("name", ["gateway", "replay"])
def test_subcommand_help_has_options_and_examples(name):
    r = pfdoa(name, "--help")
    assert r.returncode == 0
    assert "examples:" in r.stdout and f"pfdoa {name} " in r.stdout
    assert "--config" in r.stdout and "--method" in r.stdout and "--out" in r.stdout


def test_every_subcommand_help_works():
    for name, _ in _command_modules():
        r = pfdoa(name, "--help")
        assert r.returncode == 0, (name, r.stderr)
        assert r.stdout.startswith("usage: pfdoa " + name)


def test_gateway_help_names_inputs_and_methods():
    from pfdoa.estimators import METHODS

    out = pfdoa("gateway", "--help").stdout
    for word in ("--serial", "--can", "--stdin", "--replay-capture", "--capture", "--odom", "socketcan:can0",
                 "slcan:", "socket://", *METHODS):
        assert word in out


BAD = [
    ("missing key", lambda t: t.replace("path_loss_exponent = 2.2\n", ""), "radio.path_loss_exponent"),
    ("collinear", lambda t: t.replace("x = 4.0\ny = 0.0", "x = 0.0\ny = 8.0"), "collinear"),
    ("duplicate id", lambda t: t.replace("id = 1", "id = 0"), "duplicate"),
    ("nan", lambda t: t.replace("x = 4.0", "x = nan"), "finite"),
    ("wrong type", lambda t: t.replace("rssi_at_1m_dbm = -45.0", 'rssi_at_1m_dbm = "loud"'), "number"),
    ("gateway wrong type", lambda t: t + '[gateway]\nset_timeout_s = "soon"\n', "gateway.set_timeout_s"),
    ("gateway unknown key", lambda t: t + "[gateway]\nbaud = 9600\n", "gateway.baud"),
    ("gateway out of range", lambda t: t + "[gateway]\nmax_open_sets = 0\n", "gateway.max_open_sets"),
    ("gateway bad mode", lambda t: t + '[gateway]\nmode = "magic"\n', "gateway.mode"),
    ("gateway nan", lambda t: t + "[gateway]\nwindow_s = nan\n", "gateway.window_s"),
    ("output format", lambda t: t + '[output]\nformat = "xml"\n', "output.format"),
    ("estimator method", lambda t: t + '[estimator]\nmethod = "oracle"\n', "method"),
    ("syntax", lambda t: t.replace("[radio]", "[radio"), "site.toml"),
]


@pytest.mark.parametrize("command", ["gateway", "replay"])
@pytest.mark.parametrize("label,edit,words", BAD, ids=[b[0] for b in BAD])
def test_bad_configuration_one_line_exit_2(tmp_path, command, label, edit, words):
    site = tmp_path / "site.toml"
    site.write_text(edit(GOOD))
    trace = tmp_path / "t.csv"
    trace.write_text(TRACE)
    args = ["--config", str(site)]
    args = [command, *args, "--stdin"] if command == "gateway" else [command, str(trace), *args]
    r = pfdoa(*args, stdin=subprocess.DEVNULL)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith("pfdoa: error: ") and words in lines[0]
    assert "Traceback" not in r.stderr


def test_missing_config_file_and_no_input(tmp_path):
    r = pfdoa("gateway", "--config", str(tmp_path / "none.toml"), "--stdin")
    assert r.returncode == 2 and "cannot read" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    site = tmp_path / "site.toml"
    site.write_text(GOOD)
    r = pfdoa("gateway", "--config", str(site))
    assert r.returncode == 2 and "no input" in r.stderr
    r = pfdoa("gateway", "--config", str(site), "--can", "nonsense")
    assert r.returncode == 2 and "INTERFACE:CHANNEL" in r.stderr
    r = pfdoa("gateway", "--config", str(site), "--replay-capture", str(tmp_path / "x.cap"))
    assert r.returncode == 2 and "x.cap" in r.stderr


def test_bad_trace_is_one_line_exit_2(tmp_path):
    site = tmp_path / "site.toml"
    site.write_text(GOOD)
    trace = tmp_path / "t.csv"
    trace.write_text("t,anchor,rssi_dbm\n0.0,0,loud\n")
    r = pfdoa("replay", str(trace), "--config", str(site))
    assert r.returncode == 2 and "t.csv:2" in r.stderr and "Traceback" not in r.stderr


def test_replay_csv_output(tmp_path):
    site = tmp_path / "site.toml"
    site.write_text(GOOD)
    trace = tmp_path / "t.csv"
    trace.write_text(TRACE)
    r = pfdoa("-q", "replay", str(trace), "--config", str(site), "--method", "wcl", "--format", "csv")
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    assert lines[0] == ("t,x,y,sigma,doa,seq,anchors,missing,stale,rebooted,r95,cov,lost,frame_id,stamp,beacon,heading,"
                        "heading_var,room,room_p,floor,floor_p")
    assert [ln.split(",")[0] for ln in lines[1:]] == ["0.0", "1.0"]
    assert all(ln.split(",")[6] == "0;1;2" for ln in lines[1:])
