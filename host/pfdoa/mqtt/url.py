"""The broker address and credentials: ``mqtt[s]://[user@]host[:port]/prefix``.

* ``mqtt://`` is plain TCP (default port 1883), ``mqtts://`` TLS (default port 8883),
  verified against the system's CA store or ``ca_file``.
* ``user`` is the MQTT user name. A password is never part of the URL (it would show in
  ``ps`` and shell history): it comes from a file (``--mqtt-password-file``: its first
  line) or from the environment variable ``PFDOA_MQTT_PASSWORD``; the file wins.
* ``prefix`` is the topic prefix of everything the gateway publishes (``pfdoa`` when the
  URL has no path): one or more topic levels, no wildcards, no empty levels, not starting
  with ``$`` (MQTT 4.7.2: brokers keep ``$`` topics such as ``$SYS`` for themselves; a
  publish there is dropped or refused while the client counts it delivered).

Every mistake is one :class:`pfdoa.errors.InputError` line naming the option (exit 2).
"""

from __future__ import annotations

import logging
import os
import re
import stat
from dataclasses import dataclass
from urllib.parse import unquote, urlsplit

from pfdoa.errors import InputError

log = logging.getLogger(__name__)

PASSWORD_ENV = "PFDOA_MQTT_PASSWORD"
DEFAULT_PREFIX = "pfdoa"
DEFAULT_PORTS = {"mqtt": 1883, "mqtts": 8883}
MAX_PASSWORD_BYTES = 65535  # MQTT's binary-data limit for the password field
# Characters that change a topic's meaning (wildcards, level separator) or are invalid in
# one (NUL, MQTT 4.7.3).
TOPIC_SPECIAL = frozenset("+#/\x00")
RESERVED = "$"  # a first topic level starting with it is the broker's own (MQTT 4.7.2)


@dataclass(frozen=True)
class MqttUrl:
    host: str
    port: int
    prefix: str
    tls: bool = False
    user: str | None = None

    def __str__(self) -> str:  # never carries a password, so it can be logged
        user = f"{self.user}@" if self.user else ""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{'mqtts' if self.tls else 'mqtt'}://{user}{host}:{self.port}/{self.prefix}"


def _not_reserved(topic: str, what: str) -> None:
    if topic.startswith(RESERVED):
        raise ValueError(f"{what} {topic!r} starts with '$': brokers keep such topics for themselves "
                         "(MQTT 4.7.2) and drop what clients publish there")


def check_topic_prefix(prefix: str, what: str = "topic prefix") -> str:
    """A publish topic prefix: levels separated by ``/``, none empty, no wildcard or NUL,
    not a broker's own ``$`` topic."""
    if not prefix:
        raise ValueError(f"empty {what}")
    _not_reserved(prefix, what)
    for level in prefix.split("/"):
        if not level:
            raise ValueError(f"{what} {prefix!r} has an empty level")
        if TOPIC_SPECIAL & set(level):
            raise ValueError(f"{what} {prefix!r} contains a wildcard (+, #) or NUL")
    if len(prefix.encode("utf-8")) > 1024:
        raise ValueError(f"{what} longer than 1024 bytes")
    return prefix


def check_topic_filter(topic_filter: str, what: str = "topic filter") -> str:
    """A subscription filter: ``+`` only as a whole level, ``#`` only as the whole last level,
    not on the broker's own ``$`` topics (anchors cannot publish there)."""
    if not topic_filter:
        raise ValueError(f"empty {what}")
    _not_reserved(topic_filter, what)
    levels = topic_filter.split("/")
    for i, level in enumerate(levels):
        if "\x00" in level:
            raise ValueError(f"{what} {topic_filter!r} contains NUL")
        if "#" in level and (level != "#" or i != len(levels) - 1):
            raise ValueError(f"{what} {topic_filter!r}: '#' must be the whole last level")
        if "+" in level and level != "+":
            raise ValueError(f"{what} {topic_filter!r}: '+' must be a whole level")
    return topic_filter


def parse_url(url: str, option: str = "--mqtt") -> MqttUrl:
    """Parse and check a broker URL; InputError naming ``option`` on any mistake."""

    # A password typed into the URL anyway is not repeated in the message.
    shown = re.sub(r"(//[^/@:]*):[^/@]*@", r"\1:***@", url)

    def bad(problem: str) -> InputError:
        return InputError(f"{option} {shown!r}: {problem} (expected mqtt[s]://[user@]host[:port]/prefix)")

    if "#" in url:  # urlsplit would take it for a fragment
        raise bad("'#' is a topic wildcard")
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:  # a port that is not a number or out of 0..65535
        raise bad(str(exc)) from None
    scheme = parts.scheme.lower()
    if scheme not in DEFAULT_PORTS:
        raise bad(f"unknown scheme {parts.scheme or '(none)'!r}")
    if parts.password is not None:
        raise bad(f"a password does not belong in the URL; use --mqtt-password-file or {PASSWORD_ENV}")
    if not parts.hostname:
        raise bad("no host")
    if parts.query or parts.fragment:
        raise bad("query strings and fragments are not used")
    if port == 0:
        raise bad("port 0")
    user = unquote(parts.username) if parts.username else None
    prefix = unquote(parts.path[1:] if parts.path.startswith("/") else parts.path).rstrip("/")
    try:
        prefix = check_topic_prefix(prefix or DEFAULT_PREFIX)
    except ValueError as exc:
        raise bad(str(exc)) from None
    return MqttUrl(host=parts.hostname, port=port or DEFAULT_PORTS[scheme], prefix=prefix,
                   tls=scheme == "mqtts", user=user)


def read_password(path: str | None, environ: dict[str, str] | None = None,
                  option: str = "--mqtt-password-file") -> str | None:
    """The password from ``path`` (its first line) or else ``$PFDOA_MQTT_PASSWORD``; None if neither.

    A file that others can read is used, with a warning (as ssh does for keys, but not
    refused: a container's mounted secret is often mode 0644).
    """
    env = os.environ if environ is None else environ
    if path is None:
        pw = env.get(PASSWORD_ENV)
        return pw if pw else None
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_PASSWORD_BYTES + 2)
        mode = os.stat(path).st_mode
    except OSError as exc:
        raise InputError(f"{option} {path}: cannot read: {exc.strerror or exc}") from None
    line = raw.split(b"\n", 1)[0].rstrip(b"\r")
    if len(line) > MAX_PASSWORD_BYTES:
        raise InputError(f"{option} {path}: password longer than {MAX_PASSWORD_BYTES} bytes")
    try:
        pw = line.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{option} {path}: not UTF-8 text") from None
    if not pw:
        raise InputError(f"{option} {path}: the first line is empty")
    if stat.S_IMODE(mode) & 0o077:
        log.warning("%s %s: readable by other users (chmod 600 it)", option, path)
    return pw


def check_credentials(url: MqttUrl, password: str | None, option: str = "--mqtt") -> None:
    """MQTT 3.1.1 (3.1.2.9) allows a password only together with a user name."""
    if password is not None and not url.user:
        raise InputError(f"{option} {url}: a password was given but the URL names no user (mqtt://USER@host/...)")
