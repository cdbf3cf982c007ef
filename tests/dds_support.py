"""DDS on the loopback for the ROS 2 tests (not a test module).

* :func:`peer_binary` - the Fast DDS peer (tests/ros2/ros2_peer.cpp and fastddsgen's code of
  tests/ros2/ros2_msgs.idl), built with Debian's Fast DDS once and kept under
  build/ros2-peer/<hash of its sources>/ (a file lock keeps two pytest workers from building
  it at once; ``tools/bootstrap.sh dds`` installs what it needs);
* :func:`loopback_env` - the environment that pins Cyclone DDS (the gateway's) to the ``lo``
  interface: no multicast, peers found by unicast to 127.0.0.1. The peer pins itself (UDPv4
  on 127.0.0.1 only, no shared memory). Each test takes its own random domain id;
* :class:`Peer` - the peer as a process whose JSON lines are collected as they come;
* :func:`wait_until` - waits for something observable; the timeout only bounds a hang.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import random
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path
from typing import Callable

REPO = Path(__file__).resolve().parents[1]
SOURCES = REPO / "tests" / "ros2"
BUILD = REPO / "build" / "ros2-peer"
HANG_S = 120.0  # bounds a hang; nothing waits for it when things work

LOOPBACK_CYCLONE = (
    '<CycloneDDS><Domain id="any"><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>60</MaxAutoParticipantIndex>"
    '<Peers><Peer address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>'
)


def loopback_env(base: dict | None = None) -> dict:
    env = dict(os.environ if base is None else base)
    env["CYCLONEDDS_URI"] = LOOPBACK_CYCLONE
    env.pop("ROS_DOMAIN_ID", None)
    return env


def free_domain() -> int:
    """A random DDS domain id, so concurrent tests (and anything else here) do not meet."""
    return random.SystemRandom().randrange(1, 230)


def _need(tool: str) -> str:
    path = shutil.which(tool)
    if path is None:
        raise AssertionError(f"{tool} is missing: the DDS tests need Debian's Fast DDS toolchain "
                             "(tools/bootstrap.sh dds: libfastrtps-dev fastddsgen g++)")
    return path


def peer_binary() -> Path:
    """The built peer (built now if its sources changed); seconds it took are in ``.build_s``."""
    sources = sorted(SOURCES.glob("*"))
    key = hashlib.sha256(b"".join(p.name.encode() + p.read_bytes() for p in sources)).hexdigest()[:16]
    out = BUILD / key
    exe = out / "ros2_peer"
    BUILD.mkdir(parents=True, exist_ok=True)
    with open(BUILD / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if exe.exists():
            return exe
        fastddsgen, gxx = _need("fastddsgen"), _need("g++")
        tmp = out.with_name(key + ".tmp")
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir(parents=True)
        t0 = time.monotonic()
        for p in sources:
            shutil.copy2(p, tmp / p.name)
        gen = subprocess.run([fastddsgen, "-replace", "-d", str(tmp), str(tmp / "ros2_msgs.idl")],
                             capture_output=True, text=True, timeout=600, cwd=tmp)
        assert gen.returncode == 0 and (tmp / "ros2_msgsPubSubTypes.cxx").exists(), gen.stdout + gen.stderr
        cc = subprocess.run([gxx, "-std=c++14", "-O0", "-Wall", "-Wextra", "-I", str(tmp), "-o", str(tmp / "ros2_peer"),
                             str(tmp / "ros2_peer.cpp"), str(tmp / "ros2_msgs.cxx"),
                             str(tmp / "ros2_msgsPubSubTypes.cxx"), "-lfastrtps", "-lfastcdr", "-lpthread"],
                            capture_output=True, text=True, timeout=900)
        assert cc.returncode == 0, "building the Fast DDS peer failed (tools/bootstrap.sh dds installs " \
                                   "libfastrtps-dev, fastddsgen, g++):\n" + cc.stderr[-3000:]
        (tmp / ".build_s").write_text(f"{time.monotonic() - t0:.1f}\n")
        os.replace(tmp, out)
    return exe


def wait_until(what: str, check: Callable[[], object], timeout: float = HANG_S, proc=None,
               detail: Callable[[], object] | None = None):
    """``check()``'s first true value; AssertionError naming ``what`` after ``timeout`` (a hang),
    or at once when ``proc`` (a process the wait depends on) has ended; ``detail()``, what
    explains a hang (counters), is added to the message."""
    end = time.monotonic() + timeout
    while True:
        v = check()
        if v:
            return v
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"{what}: the process ended first (exit {proc.returncode})")
        if time.monotonic() > end:
            raise AssertionError(f"{what}: not within {timeout:.0f} s" + (f"; {detail()}" if detail else ""))
        time.sleep(0.02)


class Peer:
    """The Fast DDS peer as a process; :attr:`lines` are its JSON lines as they came."""

    def __init__(self, domain: int, *args: str, stdin=None) -> None:
        self.proc = subprocess.Popen([str(peer_binary()), str(domain), *args], stdin=stdin, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        self.lines: list[dict] = []
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            with self._lock:
                self.lines.append(json.loads(line))

    def snapshot(self) -> list[dict]:
        with self._lock:
            return list(self.lines)

    def samples(self, topic: str) -> list[dict]:
        return [d["msg"] for d in self.snapshot() if d.get("topic") == topic and "msg" in d]

    def matched(self, topic: str) -> int:
        counts = [d["count"] for d in self.snapshot() if d.get("event") == "matched" and d["topic"] == topic]
        return counts[-1] if counts else 0

    def event(self, name: str) -> dict | None:
        return next((d for d in self.snapshot() if d.get("event") == name), None)

    def wait(self, what: str, check: Callable[["Peer"], object], timeout: float = HANG_S):
        return wait_until(what, lambda: check(self), timeout, self.proc)

    def signal(self, sig: int) -> None:
        self.proc.send_signal(sig)

    def stop(self) -> None:
        """SIGTERM: the peer leaves the graph cleanly (its endpoints unmatch at once)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGCONT)
            self.proc.terminate()
            try:
                self.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._thread.join(timeout=10)
