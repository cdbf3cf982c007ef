"""``c``: the real anchor firmware core (firmware/core) in-process, through ctypes.

The library is built from the same C sources as the Cortex-M images. In a checkout
``make -C firmware host-lib`` builds ``firmware/build/host/libpfdoa_anchor.so`` (rebuilt
when a source is newer); from the sources a pip installation ships
(:mod:`pfdoasim.firmware`) it is compiled once with the C compiler (``$CC``, else ``cc``)
into the user cache, under a name that hashes the sources and the compiler, so an upgraded
package never loads a stale library. Each emulated anchor owns a ``pfdoa_anchor_t``
(``pfdoa_anchor_sizeof()`` bytes allocated here) and a HAL (firmware/core/include/
pfdoa_hal.h) whose callbacks are Python functions: ``uart_write`` / ``can_send`` append
to the anchor's outbox, ``config_load`` / ``config_store`` and the filter storage
(``pfdoa_filter_storage_t``) use a per-anchor "flash" (configuration and beacon filter
table) that survives reboots within a run.
"""

from __future__ import annotations

import ctypes as C
import hashlib
import logging
import os
import shlex
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any, ClassVar

from pfdoa.errors import InputError
from pfdoa.protocol import defs
from pfdoa.protocol.config import AnchorConfig
from pfdoa.protocol.messages import RadioTx
from pfdoa.protocol.uart import encode_uart
from pfdoasim import firmware
from pfdoasim.backends.base import AUTH_REASONS, Backend, OutboxCore, sil_peer_address

log = logging.getLogger(__name__)

LIB_NAME = "libpfdoa_anchor.so"
# Compiling the packaged sources (no Makefile there): the host library's flags without the
# warnings (the checkout's build keeps -Werror; a user's newer compiler must not fail here).
PACKAGED_CFLAGS = ("-std=c99", "-O2", "-fPIC", "-shared")
TRANSPORT_UART = 0x01  # pfdoa_anchor.h, PFDOA_TRANSPORT_* (the C API, not the wire)
TRANSPORT_CAN = 0x02
CONFIG_LEN = defs.CONFIG_LEN

TICK_FN = C.CFUNCTYPE(C.c_uint32, C.c_void_p)
UART_FN = C.CFUNCTYPE(C.c_int32, C.c_void_p, C.POINTER(C.c_uint8), C.c_size_t)
CAN_FN = C.CFUNCTYPE(C.c_int32, C.c_void_p, C.c_uint16, C.POINTER(C.c_uint8), C.c_uint8)
LOAD_FN = C.CFUNCTYPE(C.c_int32, C.c_void_p, C.POINTER(C.c_uint8))
STORE_FN = C.CFUNCTYPE(C.c_int32, C.c_void_p, C.POINTER(C.c_uint8))
SEND_FN = C.CFUNCTYPE(C.c_int32, C.c_void_p, C.POINTER(C.c_uint8), C.c_size_t)


class Hal(C.Structure):
    """pfdoa_hal_t, field for field (pfdoa_hal.h)."""

    _fields_ = [
        ("ctx", C.c_void_p),
        ("tick_ms", TICK_FN),
        ("uart_write", UART_FN),
        ("can_send", CAN_FN),
        ("config_load", LOAD_FN),
        ("config_store", STORE_FN),
    ]


class FilterStorage(C.Structure):
    """pfdoa_filter_storage_t (pfdoa_hal.h)."""

    _fields_ = [("ctx", C.c_void_p), ("load", LOAD_FN), ("store", STORE_FN)]


class PeerRadio(C.Structure):
    """pfdoa_peer_radio_t (pfdoa_peer.h)."""

    _fields_ = [("ctx", C.c_void_p), ("send", SEND_FN), ("radio", C.c_uint8),
                ("address", C.c_uint8 * defs.IEEE802154_EXT_ADDR_LEN)]


class Rx(C.Structure):
    """pfdoa_rx_t (pfdoa_anchor.h)."""

    _fields_ = [("tick_ms", C.c_uint32), ("rssi_dbm", C.c_int8), ("channel", C.c_uint8), ("lqi", C.c_uint8)]


class RadioReading(C.Structure):
    _fields_ = [
        ("tick_ms", C.c_uint32),
        ("seq", C.c_uint16),
        ("rssi_dbm", C.c_int8),
        ("channel", C.c_uint8),
        ("lqi", C.c_uint8),
        ("radio", C.c_uint8),
    ]


def checkout_library(tree: firmware.FirmwareTree) -> Path:
    """The library a checkout's ``make -C firmware host-lib`` builds."""
    return tree.build_dir / "host" / LIB_NAME


def build_library(tree: firmware.FirmwareTree | None = None) -> Path:
    """Build the C library from the located firmware tree; returns its path (InputError when
    that is impossible: no tree, no compiler, a failed build)."""
    tree = tree or firmware.locate()
    if tree.checkout:
        lib = checkout_library(tree)
        log.info("building the anchor core: make -C %s host-lib", tree.root)
        with firmware.build_lock(tree.build_dir):
            r = subprocess.run(["make", "-s", "-C", str(tree.root), "host-lib"], capture_output=True, text=True)
        if r.returncode != 0 or not lib.exists():
            raise InputError(f"make -C {tree.root} host-lib failed:\n{r.stdout}{r.stderr}".rstrip())
        return lib
    return _compile_packaged(tree)


def _packaged_sources(tree: firmware.FirmwareTree) -> tuple[list[Path], list[Path]]:
    core = tree.part("core")
    srcs = sorted((core / "src").glob("*.c"))
    hdrs = sorted((core / "include").glob("*.h")) + sorted((core / "src").glob("*.h"))
    if not srcs:
        raise InputError(f"no C sources in {core / 'src'}")
    return srcs, hdrs


def _compile_packaged(tree: firmware.FirmwareTree) -> Path:
    """The packaged sources compiled into the user cache (once per sources and compiler)."""
    cc = shlex.split(os.environ.get("CC") or "cc")
    if not cc or shutil.which(cc[0]) is None:
        raise InputError(f"the anchor core must be compiled from {tree.root / 'core'} but there is no C compiler "
                         f"({' '.join(cc) or 'cc'} not found): install one (apt-get install gcc) or pass --core-lib")
    srcs, hdrs = _packaged_sources(tree)
    h = hashlib.sha256(" ".join(cc + list(PACKAGED_CFLAGS)).encode())
    for f in srcs + hdrs:
        h.update(f.name.encode() + b"\0" + f.read_bytes())
    out_dir = firmware.cache_dir() / f"core-{h.hexdigest()[:16]}"
    lib = out_dir / LIB_NAME
    if lib.exists():
        return lib
    out_dir.mkdir(parents=True, exist_ok=True)
    core = tree.part("core")
    # Built under a temporary name and renamed: two simulators starting at once never load half a file.
    fd, tmp = tempfile.mkstemp(prefix=".build-", suffix=".so", dir=out_dir)
    os.close(fd)
    cmd = [*cc, *PACKAGED_CFLAGS, "-I", str(core / "include"), "-I", str(core / "src"), *map(str, srcs), "-o", tmp]
    log.info("compiling the anchor core into %s", lib)
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        os.unlink(tmp)
        raise InputError(f"compiling the anchor core failed ({shlex.join(cmd)}):\n{r.stdout}{r.stderr}".rstrip())
    os.replace(tmp, lib)
    return lib


class CoreLibrary:
    """The loaded shared library (once per process); :meth:`factory` makes anchors."""

    _cache: ClassVar[dict[str, CoreLibrary]] = {}

    def __init__(self, path: Path) -> None:
        try:
            self.lib = C.CDLL(str(path))
        except OSError as exc:
            raise InputError(f"cannot load the anchor core {path}: {exc}") from None
        self.path = path
        L = self.lib
        L.pfdoa_anchor_sizeof.restype = C.c_size_t
        L.pfdoa_anchor_sizeof.argtypes = []
        L.pfdoa_anchor_init.restype = C.c_int32
        L.pfdoa_anchor_init.argtypes = [C.c_void_p, C.POINTER(Hal), C.c_uint8, C.c_uint8]
        L.pfdoa_anchor_use_filter_storage.restype = C.c_int32
        L.pfdoa_anchor_use_filter_storage.argtypes = [C.c_void_p, C.POINTER(FilterStorage)]
        L.pfdoa_anchor_use_peer_radio.restype = C.c_int32
        L.pfdoa_anchor_use_peer_radio.argtypes = [C.c_void_p, C.POINTER(PeerRadio)]
        L.pfdoa_anchor_on_radio.restype = C.c_int32
        L.pfdoa_anchor_on_radio.argtypes = [C.c_void_p, C.POINTER(RadioReading)]
        L.pfdoa_anchor_poll.restype = C.c_int32
        L.pfdoa_anchor_poll.argtypes = [C.c_void_p, C.c_uint32]
        L.pfdoa_anchor_on_uart_rx.restype = C.c_int32
        L.pfdoa_anchor_on_uart_rx.argtypes = [C.c_void_p, C.c_char_p, C.c_size_t]
        L.pfdoa_anchor_on_can_rx.restype = C.c_int32
        L.pfdoa_anchor_on_can_rx.argtypes = [C.c_void_p, C.c_uint16, C.c_char_p, C.c_uint8]
        for name in ("pfdoa_anchor_on_ble_pdu", "pfdoa_anchor_on_802154"):
            fn = getattr(L, name)
            fn.restype = C.c_int32
            fn.argtypes = [C.c_void_p, C.POINTER(Rx), C.c_char_p, C.c_size_t]
        L.pfdoa_anchor_on_ble_adv.restype = C.c_int32
        L.pfdoa_anchor_on_ble_adv.argtypes = [C.c_void_p, C.POINTER(Rx), C.c_char_p, C.c_char_p, C.c_size_t]
        for name, res in (("pfdoa_anchor_dropped_events", C.c_uint16), ("pfdoa_anchor_rx_errors", C.c_uint16),
                          ("pfdoa_anchor_spikes", C.c_uint16), ("pfdoa_anchor_reports_sent", C.c_uint32),
                          ("pfdoa_anchor_tx_failures", C.c_uint32), ("pfdoa_anchor_config_hash", C.c_uint16),
                          ("pfdoa_anchor_filter_hash", C.c_uint16)):
            fn = getattr(L, name)
            fn.restype = res
            fn.argtypes = [C.c_void_p]
        L.pfdoa_anchor_auth_rejected.restype = C.c_uint16
        L.pfdoa_anchor_auth_rejected.argtypes = [C.c_void_p, C.c_int32]
        self.size = int(L.pfdoa_anchor_sizeof())

    @classmethod
    def load(cls, path: str | os.PathLike | None = None) -> CoreLibrary:
        if path is None:
            p = default_library()
        else:
            p = Path(path)
            if not p.exists():
                raise InputError(f"anchor core library {p} does not exist")
        key = str(p.resolve())
        if key not in cls._cache:
            cls._cache[key] = cls(p)
        return cls._cache[key]

    def factory(self) -> CoreFactory:
        """A fresh set of anchors (their flash starts with the scenario's settings)."""
        return CoreFactory(self)


class CoreFactory:
    """An :data:`AnchorFactory` for one simulation: each anchor's flash (stored
    configuration) lives here, so it survives the anchor's reboots but not the run."""

    def __init__(self, core: CoreLibrary) -> None:
        self.core = core
        self.flash: dict[int, bytes] = {}
        self.filter_flash: dict[int, bytes] = {}  # the stored beacon filter tables
        self.peer_radio: int | None = None  # the radio anchors send their advertisement on (None: none)
        # True: each advertisement also goes out on the UART as a RADIO_TX frame, as the QEMU
        # SIL image sends it (the QEMU anchors' shadow cores)
        self.radio_tx_on_uart = False

    def __call__(self, anchor_id: int, can: bool, settings: Any, boot_tick: int) -> CAnchor:
        if settings is not None and anchor_id not in self.flash:
            self.flash[anchor_id] = AnchorConfig.of(settings).pack()
        return CAnchor(self.core, self.flash, anchor_id, can, boot_tick, self.filter_flash, self.peer_radio,
                       self.radio_tx_on_uart)


_DEFAULT: dict[str, Path] = {}  # firmware root -> its library, resolved once per process


def default_library() -> Path:
    """The library for the located firmware tree, built when missing (or, in a checkout,
    when a core source is newer: what ``make`` would rebuild)."""
    tree = firmware.locate()
    key = str(tree.root)
    if key in _DEFAULT:
        return _DEFAULT[key]  # built and loaded once per process
    if not tree.checkout:
        p = _compile_packaged(tree)
    else:
        p = checkout_library(tree)
        if not p.exists():
            build_library(tree)
        elif _stale(p, tree):
            try:
                build_library(tree)
            except InputError as exc:
                # A half-edited source tree should not stop a simulation that has a library.
                log.warning("using the existing %s: rebuilding failed: %s", p, str(exc).splitlines()[-1])
    _DEFAULT[key] = p
    return p


def _stale(lib: Path, tree: firmware.FirmwareTree) -> bool:
    """The library is older than a core source (so `make` would rebuild it)."""
    t = lib.stat().st_mtime
    return any(f.stat().st_mtime > t for f in tree.part("core").rglob("*.[ch]"))


class CAnchor(OutboxCore):
    """One ``pfdoa_anchor_t`` and its HAL."""

    def __init__(self, core: CoreLibrary, flash: dict[int, bytes], anchor_id: int, can: bool,
                 boot_tick: int, filter_flash: dict[int, bytes] | None = None, peer_radio: int | None = None,
                 radio_tx_on_uart: bool = False) -> None:
        super().__init__()
        self.core = core
        self.flash = flash
        self.filter_flash = filter_flash if filter_flash is not None else {}
        self.anchor_id = anchor_id
        self.lib = core.lib
        self.buf = C.create_string_buffer(core.size)
        self._boot_tick = boot_tick & 0xFFFFFFFF
        self.store_failures = 0
        # The callbacks must outlive the instance's use: keep them on self.
        self._cbs = (
            TICK_FN(lambda ctx: self._boot_tick),
            UART_FN(self._uart_write),
            CAN_FN(self._can_send),
            LOAD_FN(self._config_load),
            STORE_FN(self._config_store),
            LOAD_FN(self._filters_load),
            STORE_FN(self._filters_store),
            SEND_FN(self._peer_send),
        )
        self.hal = Hal(None, *self._cbs[:5])
        self.storage = FilterStorage(None, *self._cbs[5:7])
        rc = self.lib.pfdoa_anchor_init(self.buf, C.byref(self.hal), anchor_id, TRANSPORT_CAN if can else TRANSPORT_UART)
        if rc == 0:
            rc = self.lib.pfdoa_anchor_use_filter_storage(self.buf, C.byref(self.storage))
        self.peer_radio = peer_radio
        self.radio_tx_on_uart = radio_tx_on_uart
        self._tick = self._boot_tick  # the last tick the core was given (a RADIO_TX frame's)
        if rc == 0 and peer_radio is not None:
            address = sil_peer_address(peer_radio, anchor_id)
            self.radio_struct = PeerRadio(None, self._cbs[7], peer_radio,
                                          (C.c_uint8 * defs.IEEE802154_EXT_ADDR_LEN)(*address.ljust(8, b"\x00")))
            rc = self.lib.pfdoa_anchor_use_peer_radio(self.buf, C.byref(self.radio_struct))
        if rc != 0:
            raise InputError(f"pfdoa_anchor_init(anchor {anchor_id}) failed: {rc}")
        self._reading = RadioReading()
        self._rx = Rx()

    # -- HAL callbacks (called from C; must not raise) ---------------------------------------
    def _uart_write(self, ctx, data, n) -> int:
        self._uart += C.string_at(data, n)
        return int(n)

    def _can_send(self, ctx, can_id, data, dlc) -> int:
        self._can.append((int(can_id), C.string_at(data, dlc)))
        return 0

    def _peer_send(self, ctx, frame, n) -> int:
        data = C.string_at(frame, n)
        assert self.peer_radio is not None  # only a core with a radio is given this callback
        self._radio.append((self.peer_radio, data))
        if self.radio_tx_on_uart:
            self._uart += encode_uart(RadioTx(self._tick, self.peer_radio, len(data), data), self.anchor_id)
        return 0

    def _config_load(self, ctx, out) -> int:
        stored = self.flash.get(self.anchor_id)
        if stored is None:
            return -1
        C.memmove(out, stored, CONFIG_LEN)
        return 0

    def _config_store(self, ctx, cfg) -> int:
        self.flash[self.anchor_id] = C.string_at(cfg, CONFIG_LEN)
        return 0

    def _filters_load(self, ctx, out) -> int:
        stored = self.filter_flash.get(self.anchor_id)
        if stored is None:
            return -1
        C.memmove(out, stored, defs.FILTER_TABLE_LEN)
        return 0

    def _filters_store(self, ctx, table) -> int:
        self.filter_flash[self.anchor_id] = C.string_at(table, defs.FILTER_TABLE_LEN)
        return 0

    # -- AnchorCore -------------------------------------------------------------------------
    def radio(self, seq: int, rssi_dbm: int, channel: int, lqi: int, radio: int, tick_ms: int) -> None:
        r = self._reading
        r.tick_ms = tick_ms & 0xFFFFFFFF
        r.seq = seq & 0xFFFF
        r.rssi_dbm = max(-128, min(127, rssi_dbm))
        r.channel = channel
        r.lqi = lqi
        r.radio = radio
        self.lib.pfdoa_anchor_on_radio(self.buf, C.byref(r))

    def _set_rx(self, rssi_dbm: int, channel: int, lqi: int, tick_ms: int) -> Rx:
        rx = self._rx
        rx.tick_ms = tick_ms & 0xFFFFFFFF
        rx.rssi_dbm = max(-128, min(127, rssi_dbm))
        rx.channel = channel
        rx.lqi = lqi
        return rx

    # Raw receptions, matched by the core against its beacon filter table (SPEC 3.1-3.3).
    def ble_adv(self, adv_a: bytes, adv_data: bytes, rssi_dbm: int, channel: int, tick_ms: int) -> int:
        rx = self._set_rx(rssi_dbm, channel, 0, tick_ms)
        return int(self.lib.pfdoa_anchor_on_ble_adv(self.buf, C.byref(rx), bytes(adv_a), bytes(adv_data),
                                                    len(adv_data)))

    def ble_pdu(self, pdu: bytes, rssi_dbm: int, channel: int, tick_ms: int) -> int:
        rx = self._set_rx(rssi_dbm, channel, 0, tick_ms)
        return int(self.lib.pfdoa_anchor_on_ble_pdu(self.buf, C.byref(rx), bytes(pdu), len(pdu)))

    def ieee802154(self, mpdu: bytes, rssi_dbm: int, channel: int, lqi: int, tick_ms: int) -> int:
        rx = self._set_rx(rssi_dbm, channel, lqi, tick_ms)
        return int(self.lib.pfdoa_anchor_on_802154(self.buf, C.byref(rx), bytes(mpdu), len(mpdu)))

    def poll(self, tick_ms: int) -> None:
        self._tick = tick_ms & 0xFFFFFFFF
        self.lib.pfdoa_anchor_poll(self.buf, self._tick)

    def uart_rx(self, data: bytes, tick_ms: int) -> None:
        self.lib.pfdoa_anchor_on_uart_rx(self.buf, data, len(data))
        self.poll(tick_ms)

    def can_rx(self, can_id: int, data: bytes) -> None:
        self.lib.pfdoa_anchor_on_can_rx(self.buf, can_id, data, len(data))

    def counters(self) -> dict[str, int]:
        L, b = self.lib, self.buf
        return {
            "dropped_events": int(L.pfdoa_anchor_dropped_events(b)),
            "rx_errors": int(L.pfdoa_anchor_rx_errors(b)),
            "spikes": int(L.pfdoa_anchor_spikes(b)),
            "reports_sent": int(L.pfdoa_anchor_reports_sent(b)),
            "tx_failures": int(L.pfdoa_anchor_tx_failures(b)),
            "filter_hash": int(L.pfdoa_anchor_filter_hash(b)),
        }

    def auth_rejected(self) -> dict[str, int]:
        """Its authenticated beacons' advertisements it rejected, by reason (SPEC 9.4)."""
        return {name: int(self.lib.pfdoa_anchor_auth_rejected(self.buf, code)) for name, code in AUTH_REASONS}


class CBackend(Backend):
    name = "c"

    def factory(self, core_lib: str | None = None) -> CoreFactory:
        return CoreLibrary.load(core_lib).factory()
