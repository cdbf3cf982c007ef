"""Shared by the MQTT tests: TLS files for a test broker, waiting for broker events, a plain
paho subscriber. The broker fixtures themselves are in tests/conftest.py."""

from __future__ import annotations

import shutil
import subprocess
import threading
import time
from pathlib import Path

import paho.mqtt.client as paho

from pfdoasim.fleet import Mosquitto, TlsFiles


def make_tls_files(d: Path) -> TlsFiles:
    """A throw-away CA and a server certificate for 127.0.0.1, made with the openssl tool."""
    if shutil.which("openssl") is None:
        raise AssertionError("openssl not found")
    d.mkdir(parents=True, exist_ok=True)

    def run(*args: str) -> None:
        subprocess.run(["openssl", *args], check=True, cwd=d, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)

    run("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj", "/CN=pfdoa test CA",
        "-keyout", "ca.key", "-out", "ca.crt")
    run("req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=127.0.0.1", "-keyout", "server.key", "-out", "server.csr")
    (d / "ext.cnf").write_text("subjectAltName = IP:127.0.0.1\n")
    run("x509", "-req", "-in", "server.csr", "-CA", "ca.crt", "-CAkey", "ca.key", "-CAcreateserial", "-days", "2",
        "-extfile", "ext.cnf", "-out", "server.crt")
    return TlsFiles(str(d / "ca.crt"), str(d / "server.crt"), str(d / "server.key"))


def wait_for(pred, timeout_s: float = 20.0, what: str = "condition") -> None:
    """Wait for an event on the broker; the timeout only bounds a failing test."""
    end = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.01)


class Recorder:
    """A plain paho subscriber (not our client): what any other program on the broker sees."""

    def __init__(self, b: Mosquitto, topic: str, client_id: str = "", clean_session: bool = True,
                 qos: int = 1) -> None:
        self.messages: list[tuple[str, bytes, bool]] = []  # (topic, payload, retain)
        self._lock = threading.Lock()
        self.subscribed = threading.Event()
        self.topic, self.qos = topic, qos
        self.c = paho.Client(paho.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=clean_session)
        self.c.on_connect = lambda c, u, f, rc, p: c.subscribe(self.topic, self.qos)
        self.c.on_subscribe = lambda c, u, mid, rcs, p: self.subscribed.set()
        self.c.on_message = self._on_message
        self.c.reconnect_delay_set(0.1, 0.5)
        self.c.connect_async("127.0.0.1", b.port)
        self.c.loop_start()
        assert self.subscribed.wait(10), "recorder could not subscribe"

    def _on_message(self, _c, _u, m) -> None:
        with self._lock:
            self.messages.append((m.topic, bytes(m.payload), bool(m.retain)))

    def on(self, topic: str) -> list[bytes]:
        with self._lock:
            return [p for t, p, _r in self.messages if t == topic]

    def poses(self) -> list[bytes]:
        """Every pose payload so far, in arrival order."""
        with self._lock:
            return [p for t, p, _r in self.messages if t.endswith("/pose")]

    def close(self) -> None:
        self.c.disconnect()
        self.c.loop_stop()
