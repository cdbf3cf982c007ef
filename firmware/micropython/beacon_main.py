# Entry point of the beacon on the robot (copy as main.py with pfdoa_defs.py,
# pfdoa_beacon.py and beacon_ble.py; for the authenticated beacon also pfdoa_auth.py and the
# key file). Every robot of a site needs its own BEACON_ID (static beacon) or its own key
# (authenticated beacon); the anchors are told which to follow (FILTER_SET, `pfdoa anchors`).
import beacon_ble

BEACON_ID = 0  # 0..255; an anchor follows id 0 until told otherwise
INTERVAL_MS = 100  # 20..10240: one advertisement (one sequence number) per interval
TX_POWER_DBM = 0  # applied where the port supports BLE.config(txpower=...)
# The authenticated rolling beacon (protocol/SPEC.md 9): the key file from `pfdoa anchors
# keygen` (copy it to the board, e.g. `mpremote cp robot1.key :pfdoa.key`), and the board's
# clock set to UTC (ntptime on a board with WiFi, or `TZ=UTC mpremote rtc --set`: mpremote
# sets the host's local time).
# None: the static beacon (BEACON_ID).
KEY_FILE = None  # e.g. "pfdoa.key"

beacon_ble.run(BEACON_ID, INTERVAL_MS, TX_POWER_DBM, KEY_FILE)
