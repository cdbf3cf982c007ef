# Runs event scripts (protocol/vectors/README.md) through the MicroPython anchor core and
# prints every emitted frame: `U <hex incl. 00>`, `C <3-hex id> <hex data>` or `T <hex>`
# (the anchor's own advertisement, sent on its radio).
#
#   micropython anchor_script.py [--id N] [--transport uart|can] [--boot-tick T]
#                                [--fw MAJOR.MINOR] [--store-fail] [--sil-inject]
#                                [--config OFFSET,ALPHA,SPIKE,MODE,DEC]  < script
#
# Batch mode for the differential check: a line `@ <json init>` starts a new anchor
# (fields as in a vector's "init": anchor_id, transport, boot_tick_ms, fw_major,
# fw_minor, config{...}, filters (hex), store_ok, sil_inject, peer_radio ("ble" | "802154")
# with peer_address (hex)); `@` is echoed to the output
# before its frames, so one process can run thousands of sequences.
import json
import struct
import sys

try:
    _d = __file__.rfind("/")
    sys.path.insert(0, __file__[:_d] if _d >= 0 else ".")
except NameError:
    pass

import pfdoa_defs as D  # noqa: E402
from pfdoa_anchor import TRANSPORT_CAN, TRANSPORT_UART, Anchor  # noqa: E402

_CFG_KEYS = ("offset_q8", "alpha_q8", "spike_db", "report_mode", "decimation")
_DEFAULT_CFG = struct.unpack(D.CONFIG_FMT, D.CONFIG_DEFAULT)
_PEER_RADIOS = {"ble": D.RADIO_BLE, "802154": D.RADIO_IEEE802154}
_TRANSPORTS = {"uart": TRANSPORT_UART, "can": TRANSPORT_CAN,
               "both": TRANSPORT_UART | TRANSPORT_CAN}


class ScriptError(Exception):
    pass


class Runner:
    """One anchor driven by script lines; emitted frames go to the `out` list."""

    def __init__(self, init, out):
        self.out = out
        cfg = None
        if "config" in init:
            c = init["config"]
            cfg = struct.pack(D.CONFIG_FMT, *[c.get(k, d) for k, d in zip(_CFG_KEYS, _DEFAULT_CFG)])
        self.stored = None
        self.store_ok = init.get("store_ok", True)
        filters = bytes.fromhex(init["filters"]) if "filters" in init else None
        peer = {}
        if "peer_radio" in init:
            peer = {"peer_send": self._peer, "peer_radio": _PEER_RADIOS[init["peer_radio"]],
                    "peer_address": bytes.fromhex(init["peer_address"])}
        # Both interfaces exist; `transport` picks the one for reports and STATUS.
        self.anchor = Anchor(
            init["anchor_id"], init.get("boot_tick_ms", 0),
            uart_write=self._uart, can_send=self._can,
            transports=_TRANSPORTS[init.get("transport", "uart")],
            config=cfg, store=self._store,
            sil_inject=init.get("sil_inject", False),
            fw=(init.get("fw_major", 1), init.get("fw_minor", 0)),
            filters=filters, store_filters=self._store, **peer)

    def _uart(self, mv):
        self.out.append("U " + bytes(mv).hex())

    def _can(self, can_id, mv):
        self.out.append("C %03x %s" % (can_id, bytes(mv).hex()))

    def _peer(self, mv):
        self.out.append("T " + bytes(mv).hex())
        return True

    def _store(self, cfg):
        if self.store_ok:
            self.stored = bytes(cfg)
        return self.store_ok

    def step(self, line):
        i = line.find("#")
        if i >= 0:
            line = line[:i]
        tok = line.split()
        if not tok:
            return
        cmd = tok[0]
        n = len(tok)
        a = self.anchor
        if cmd == "R" and n == 7:
            a.reading(int(tok[2]), int(tok[3]), int(tok[4]), int(tok[5]), int(tok[6]),
                      int(tok[1]))
        elif cmd == "B" and n == 5:
            f = _hex(tok[4])
            a.ble_pdu(f, len(f), int(tok[2]), int(tok[3]), int(tok[1]))
        elif cmd == "A" and n == 6:
            adv_a = bytes.fromhex(tok[4])
            if len(adv_a) != 6:
                raise ScriptError("AdvA is 6 bytes: " + line)
            a.ble_adv(adv_a, _hex(tok[5]), int(tok[2]), int(tok[3]), int(tok[1]))
        elif cmd == "Z" and n == 6:
            f = _hex(tok[5])
            a.ieee802154(f, len(f), int(tok[2]), int(tok[3]), int(tok[4]), int(tok[1]))
        elif cmd == "P" and n == 2:
            a.poll(int(tok[1]))
        elif cmd == "U" and n == 3:
            a.uart_rx(bytes.fromhex(tok[2]))
        elif cmd == "C" and n == 4:
            a.can_rx(int(tok[2], 16), bytes.fromhex(tok[3]))
        else:
            raise ScriptError("bad script line: " + line)


def _hex(text):
    return b"" if text == "-" else bytes.fromhex(text)


def run(init, lines):
    """Output lines of one event script run on a fresh anchor."""
    out = []
    r = Runner(init, out)
    for line in lines:
        r.step(line)
    return out


def _args(argv):
    init = {"anchor_id": 1}
    i = 0
    while i < len(argv):
        k = argv[i]
        v = argv[i + 1] if i + 1 < len(argv) else ""
        i += 2
        if k == "--id":
            init["anchor_id"] = int(v)
        elif k == "--transport":
            init["transport"] = v
        elif k == "--boot-tick":
            init["boot_tick_ms"] = int(v)
        elif k == "--fw":
            ma, mi = v.split(".")
            init["fw_major"] = int(ma)
            init["fw_minor"] = int(mi)
        elif k == "--config":
            init["config"] = dict(zip(_CFG_KEYS, [int(x) for x in v.split(",")]))
        elif k == "--store-fail":
            init["store_ok"] = False
            i -= 1
        elif k == "--sil-inject":
            init["sil_inject"] = True
            i -= 1
        else:
            raise ScriptError("unknown option " + k)
    return init


def _lines(read):
    """Lines of stdin read in large chunks (readline() costs a system call per byte
    on the unix port)."""
    rest = b""
    while True:
        chunk = read(65536)
        if not chunk:
            break
        parts = (rest + chunk).split(b"\n")
        rest = parts.pop()
        for p in parts:
            yield p.decode()
    if rest:
        yield rest.decode()


def main(argv):
    init = _args(argv)
    out = []
    runner = Runner(init, out)
    write = sys.stdout.write
    lineno = 0
    for line in _lines(sys.stdin.buffer.read):
        lineno += 1
        if line[:1] == "@":
            runner = Runner(json.loads(line[1:]), out)
            out.append("@")
        else:
            try:
                runner.step(line)
            except (ScriptError, ValueError) as e:
                sys.stderr.write("line %d: %s\n" % (lineno, e))
                return 2
        if len(out) > 256:
            write("\n".join(out))
            write("\n")
            out.clear()
    if out:
        write("\n".join(out))
        write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
