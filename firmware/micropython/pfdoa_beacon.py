# The beacon on the robot, for MicroPython (protocol/SPEC.md section 6): what it sends and
# when, without the radio (beacon_ble.py is the BLE glue). Byte-identical to the C beacon
# (firmware/beacon) and the Python reference (pfdoa.protocol.beacons): the golden vectors
# protocol/vectors/beacon.json "builds" (and auth.json "builds" for the authenticated beacon
# of SPEC 9) check all three. Integer only; the per-advertisement path reuses its buffers
# (the authenticated beacon's HMACs allocate their digests).
from micropython import const
import pfdoa_defs as D

RADIO_BLE = const(1)  # bits of Beacon(radios=...)
RADIO_IEEE802154 = const(2)
_M32 = const(0xFFFFFFFF)

ADV_DATA_LEN = const(12)  # Flags (3) + manufacturer data (9)
MPDU_LEN = const(20)  # FCF, seq, PAN, dst, src (ext), payload (SPEC 6)
AUTH_ADV_DATA_LEN = const(29)  # Flags (3) + manufacturer data header (4) + the 22-byte payload (SPEC 9.3)
AUTH_MPDU_LEN = const(37)  # the 802.15.4 header (15) + the 22-byte payload
# Frame Control of our 802.15.4 beacon: a data frame, PAN ID Compression, short
# destination, extended source, frame version 0 (IEEE 802.15.4-2015 7.2.2).
_FCF = (D.IEEE802154_FRAME_DATA | D.IEEE802154_FCF_PANID_COMP
        | (D.IEEE802154_ADDR_SHORT << D.IEEE802154_FCF_DST_MODE_SHIFT)
        | (D.IEEE802154_ADDR_EXT << D.IEEE802154_FCF_SRC_MODE_SHIFT))


def _adv_header(b, n):
    b[0] = 2  # Flags AD: length 2, type, flags
    b[1] = D.BLE_AD_FLAGS
    b[2] = D.BLE_FLAGS_GENERAL_NO_BREDR
    b[3] = 1 + 2 + n  # manufacturer AD: type, company, payload
    b[4] = D.BLE_AD_MANUFACTURER
    b[5] = D.BEACON_COMPANY_ID & 0xFF
    b[6] = D.BEACON_COMPANY_ID >> 8


def adv_data(seq, beacon_id, out=None):
    """Our beacon's AdvData (SPEC 6) into out (ADV_DATA_LEN bytes, reused when given):
    Flags, then manufacturer data: company 0xFFFF, 'P' 'F', seq u16 LE, beacon id."""
    b = out if out is not None else bytearray(ADV_DATA_LEN)
    _adv_header(b, D.BEACON_PAYLOAD_LEN)
    _payload(b, 7, seq, beacon_id)
    return b


def auth_adv_data(k, ids, counter, seq, out=None):
    """The authenticated beacon's AdvData (SPEC 9.3): Flags, then manufacturer data company
    0xFFFF with the 22-byte payload. k: pfdoa_auth.Key; ids: pfdoa_auth.derive(k, counter)."""
    import pfdoa_auth as A
    b = out if out is not None else bytearray(AUTH_ADV_DATA_LEN)
    _adv_header(b, D.AUTH_PAYLOAD_LEN)
    b[7:AUTH_ADV_DATA_LEN] = A.payload(k, counter, seq, ids)
    return b


def auth_mpdu(k, ids, counter, seq, pan_id=D.BEACON_PAN_ID_DEFAULT, out=None):
    """The authenticated beacon as an IEEE 802.15.4 data frame without FCS (SPEC 9.3): from
    the period's extended address, MAC seq = the low byte of the hidden seq."""
    import pfdoa_auth as A
    b = out if out is not None else bytearray(AUTH_MPDU_LEN)
    p = A.payload(k, counter, seq, ids)
    _mac_header(b, p[6], pan_id, ids[2])
    b[15:AUTH_MPDU_LEN] = p
    return b


def _payload(b, at, seq, beacon_id):
    b[at] = D.BEACON_MAGIC0
    b[at + 1] = D.BEACON_MAGIC1
    b[at + 2] = seq & 0xFF
    b[at + 3] = (seq >> 8) & 0xFF
    b[at + 4] = beacon_id


def adv_pdu(adv_a, data, out=None):
    """A non-connectable advertising PDU (ADV_NONCONN_IND, random address) carrying data,
    for radios driven without a BLE stack (Core Spec Vol 6 Part B 2.3)."""
    n = len(data)
    b = out if out is not None else bytearray(D.BLE_PDU_HEADER_LEN + D.BLE_ADV_A_LEN + n)
    b[0] = D.BLE_PDU_ADV_NONCONN_IND | D.BLE_PDU_TXADD
    b[1] = D.BLE_ADV_A_LEN + n
    for i in range(D.BLE_ADV_A_LEN):
        b[2 + i] = adv_a[i]
    for i in range(n):
        b[2 + D.BLE_ADV_A_LEN + i] = data[i]
    return b


def mpdu(seq, beacon_id, ext_addr, pan_id=D.BEACON_PAN_ID_DEFAULT, out=None):
    """Our beacon as an IEEE 802.15.4 data frame without FCS (SPEC 6): to the broadcast
    address on pan_id from ext_addr (8 bytes, on-air order), MAC seq = seq & 0xFF."""
    b = out if out is not None else bytearray(MPDU_LEN)
    _mac_header(b, seq & 0xFF, pan_id, ext_addr)
    _payload(b, 15, seq, beacon_id)
    return b


def _mac_header(b, mac_seq, pan_id, ext_addr):
    b[0] = _FCF & 0xFF
    b[1] = _FCF >> 8
    b[2] = mac_seq
    b[3] = pan_id & 0xFF
    b[4] = pan_id >> 8
    b[5] = D.IEEE802154_BROADCAST & 0xFF
    b[6] = D.IEEE802154_BROADCAST >> 8
    for i in range(8):
        b[7 + i] = ext_addr[i]


class Beacon:
    """Sends one advertisement every interval_ms through send(radio, frame, tx_power_dbm)
    (radio RADIO_BLE: AdvData of one advertising event; RADIO_IEEE802154: a MAC frame
    without FCS), the sequence number one up each time (wrapping). Call poll(now_ms)
    often (it sends when due, wrap-safe on a u32 tick); the buffers are reused.

    With key (16 bytes) it is the authenticated rolling beacon (SPEC 9): it needs the time,
    set_time(counter, phase_ms, now_ms) with counter = floor(Unix ms / 4096), and sends
    nothing before; .adv_a is then the period's private address (a BLE glue that can set
    the device address applies it) and .ext_addr the period's 802.15.4 address."""

    def __init__(self, send, beacon_id=0, interval_ms=D.BEACON_INTERVAL_MS_DEFAULT,
                 tx_power_dbm=D.BEACON_TX_POWER_DBM_DEFAULT, radios=RADIO_BLE,
                 ext_addr=None, pan_id=D.BEACON_PAN_ID_DEFAULT, seq=0, key=None):
        if not D.BEACON_INTERVAL_MS_MIN <= interval_ms <= D.BEACON_INTERVAL_MS_MAX:
            raise ValueError("interval_ms")
        if not 0 <= beacon_id <= 255 or not -128 <= tx_power_dbm <= 127 or not radios or radios > 3:
            raise ValueError("beacon_id, tx_power_dbm or radios")
        if key is None and radios & RADIO_IEEE802154 and (ext_addr is None or len(ext_addr) != 8):
            raise ValueError("an 802.15.4 beacon needs its 8-byte extended address")
        self._key = None
        if key is not None:
            import pfdoa_auth as A
            if len(key) != D.AUTH_KEY_LEN:
                raise ValueError("a beacon key is 16 bytes")
            self._key = A.Key(key)
        self._counter = None  # the authenticated beacon's counter and the tick its period began
        self._period_tick = 0
        self._ids_counter = None
        self._ids = None
        self.adv_a = None
        self._send = send
        self.beacon_id = beacon_id
        self.interval_ms = interval_ms
        self.tx_power_dbm = tx_power_dbm
        self.radios = radios
        self._ext = ext_addr
        self._pan = pan_id
        self.seq = seq & 0xFFFF
        self._next = None  # tick of the next advertisement; None: at the first poll
        self._adv = bytearray(AUTH_ADV_DATA_LEN if key is not None else ADV_DATA_LEN)
        self._mpdu = bytearray(AUTH_MPDU_LEN if key is not None else MPDU_LEN)

    def set_time(self, counter, phase_ms, now_ms):
        """The authenticated beacon's clock: at now_ms the counter is `counter`, its period
        having begun phase_ms ago (0..4095)."""
        if self._key is None or not 0 <= phase_ms < D.AUTH_PERIOD_MS:
            raise ValueError("set_time: an authenticated beacon and phase_ms in 0..4095")
        self._counter = counter & _M32
        self._period_tick = (now_ms - phase_ms) & _M32

    def counter(self, now_ms):
        """The counter at now_ms (None before set_time)."""
        if self._counter is None:
            return None
        periods = ((now_ms - self._period_tick) & _M32) >> D.AUTH_PERIOD_SHIFT
        self._counter = (self._counter + periods) & _M32
        self._period_tick = (self._period_tick + (periods << D.AUTH_PERIOD_SHIFT)) & _M32
        return self._counter

    def poll(self, now_ms):
        """Sends the advertisement when it is due; returns True when it sent one. As the C
        beacon: on time or a little late keeps the cadence, a stall of an interval or more
        sends once and restarts the interval from now (no burst)."""
        now_ms &= _M32
        late = None if self._next is None else (now_ms - self._next) & _M32
        if late is not None and late >= 0x80000000:
            return False  # not yet (the difference is negative)
        self.send_now(now_ms)
        base = self._next if late is not None and late < self.interval_ms else now_ms
        self._next = (base + self.interval_ms) & _M32
        return True

    def send_now(self, now_ms=0):
        if self._key is not None:
            self._send_auth(now_ms & _M32)
            return
        if self.radios & RADIO_BLE:
            self._send(RADIO_BLE, adv_data(self.seq, self.beacon_id, self._adv), self.tx_power_dbm)
        if self.radios & RADIO_IEEE802154:
            self._send(RADIO_IEEE802154, mpdu(self.seq, self.beacon_id, self._ext, self._pan, self._mpdu),
                       self.tx_power_dbm)
        self.seq = (self.seq + 1) & 0xFFFF

    def _send_auth(self, now_ms):
        c = self.counter(now_ms)
        if c is None:
            return  # no time, no counter: nothing a verifier could accept
        if c != self._ids_counter:
            import pfdoa_auth as A
            self._ids = A.derive(self._key, c)  # once a period
            self._ids_counter = c
            self.adv_a = self._ids[1]
            self._ext = self._ids[2]
        if self.radios & RADIO_BLE:
            self._send(RADIO_BLE, auth_adv_data(self._key, self._ids, c, self.seq, self._adv), self.tx_power_dbm)
        if self.radios & RADIO_IEEE802154:
            self._send(RADIO_IEEE802154, auth_mpdu(self._key, self._ids, c, self.seq, self._pan, self._mpdu),
                       self.tx_power_dbm)
        self.seq = (self.seq + 1) & 0xFFFF
