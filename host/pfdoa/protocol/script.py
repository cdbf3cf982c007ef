"""Event scripts: the shared text format that drives an anchor (protocol/vectors/README.md).

    R <tick_ms> <seq> <rssi_dbm> <channel> <lqi> <radio>   reading of beacon entry 0 (on_radio)
    B <tick_ms> <rssi_dbm> <channel> <pdu hex>            BLE advertising PDU (on_ble_pdu)
    A <tick_ms> <rssi_dbm> <channel> <AdvA hex> <AdvData hex>   AdvA + AdvData (on_ble_adv)
    Z <tick_ms> <rssi_dbm> <channel> <lqi> <mpdu hex>     IEEE 802.15.4 frame (on_802154)
    (a frame's hex is "-" when it is empty)
    P <tick_ms>                                          poll
    U <tick_ms> <hex bytes>                              bytes received on the UART
    C <tick_ms> <can id, 3 hex digits> <hex data>        CAN frame on the bus

Numbers are decimal except where hex is stated; '#' starts a comment; blank lines are
ignored. Output lines are `U <hex incl. the 00 delimiter>`, `C <3-hex-digit id> <hex>` or
`T <hex>` (the anchor's own advertisement, sent on its radio), lower-case hex.
"""

from __future__ import annotations

from typing import Iterable, Mapping

from . import defs
from .anchor_model import AnchorConfig, AnchorModel, Transmitted, WireUnit

PEER_RADIOS = {"ble": defs.RADIO_BLE, "802154": defs.RADIO_IEEE802154}  # init's peer_radio


class ScriptError(ValueError):
    """A malformed event-script line (message names the line number)."""


def format_unit(unit: WireUnit) -> str:
    """One emitted frame as an expected-output line."""
    if isinstance(unit, Transmitted):
        return "T " + unit.frame.hex()
    if isinstance(unit, (bytes, bytearray)):
        return "U " + bytes(unit).hex()
    can_id, data = unit
    return f"C {can_id:03x} {bytes(data).hex()}"


def model_from_init(init: Mapping) -> AnchorModel:
    """An AnchorModel from a vector's `init` object (README: anchor vectors)."""
    config = AnchorConfig(**init["config"]) if "config" in init else None
    filters = bytes.fromhex(init["filters"]) if "filters" in init else None
    peer = None
    if "peer_radio" in init:
        peer = (PEER_RADIOS[init["peer_radio"]], bytes.fromhex(init["peer_address"]))
    return AnchorModel(
        init["anchor_id"], init.get("transport", "uart"),
        boot_tick_ms=init.get("boot_tick_ms", 0), fw_major=init.get("fw_major", 1),
        fw_minor=init.get("fw_minor", 0), config=config, filters=filters,
        store_ok=init.get("store_ok", True), sil_inject=init.get("sil_inject", False), peer_radio=peer)


def step(model: AnchorModel, line: str, lineno: int = 0) -> list[WireUnit]:
    """Apply one script line to `model`; return the frames it emitted."""
    text = line.split("#", 1)[0].strip()
    if not text:
        return []
    tok = text.split()
    try:
        cmd, args = tok[0], tok[1:]
        if cmd == "R" and len(args) == 6:
            tick, seq, rssi, channel, lqi, radio = (int(a, 10) for a in args)
            return model.reading(tick, seq, rssi, channel, lqi, radio)
        if cmd == "B" and len(args) == 4:
            tick, rssi, channel = (int(a, 10) for a in args[:3])
            _check_rx(rssi, channel)
            return model.ble_pdu(tick, rssi, channel, _hex(args[3]))
        if cmd == "A" and len(args) == 5:
            tick, rssi, channel = (int(a, 10) for a in args[:3])
            _check_rx(rssi, channel)
            adv_a = bytes.fromhex(args[3])
            if len(adv_a) != 6:
                raise ValueError("AdvA is 6 bytes")
            return model.ble_adv(tick, rssi, channel, adv_a, _hex(args[4]))
        if cmd == "Z" and len(args) == 5:
            tick, rssi, channel, lqi = (int(a, 10) for a in args[:4])
            _check_rx(rssi, channel, lqi)
            return model.ieee802154(tick, rssi, channel, lqi, _hex(args[4]))
        if cmd == "P" and len(args) == 1:
            return model.poll(int(args[0], 10))
        if cmd == "U" and len(args) == 2:
            return model.uart_rx(int(args[0], 10), bytes.fromhex(args[1]))
        if cmd == "C" and len(args) == 3:
            return model.can_rx(int(args[0], 10), int(args[1], 16), bytes.fromhex(args[2]))
    except ValueError as e:
        raise ScriptError(f"line {lineno}: {line.strip()!r}: {e}") from None
    raise ScriptError(f"line {lineno}: {line.strip()!r}: unknown command or wrong field count")


def _hex(text: str) -> bytes:
    """A frame's hex; "-" is an empty frame."""
    return b"" if text == "-" else bytes.fromhex(text)


def _check_rx(rssi: int, channel: int, lqi: int = 0) -> None:
    if not -128 <= rssi <= 127 or not 0 <= channel <= 255 or not 0 <= lqi <= 255:
        raise ValueError("reception field out of range (rssi i8, channel u8, lqi u8)")


def run_script(init: Mapping, script: Iterable[str]) -> list[str]:
    """Run an event script through a fresh reference anchor; return the output lines."""
    model = model_from_init(init)
    out: list[str] = []
    for lineno, line in enumerate(script, 1):
        out += [format_unit(u) for u in step(model, line, lineno)]
    return out
