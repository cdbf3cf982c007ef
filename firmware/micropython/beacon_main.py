# Entry point of the beacon on the robot (copy as main.py with pfdoa_defs.py,
# pfdoa_beacon.py and beacon_ble.py). Every robot of a site needs its own BEACON_ID; the
# anchors are told which ids to follow (FILTER_SET, `pfdoa anchors`).
import beacon_ble

BEACON_ID = 0  # 0..255; an anchor follows id 0 until told otherwise
INTERVAL_MS = 100  # 20..10240: one advertisement (one sequence number) per interval
TX_POWER_DBM = 0  # applied where the port supports BLE.config(txpower=...)

beacon_ble.run(BEACON_ID, INTERVAL_MS, TX_POWER_DBM)
