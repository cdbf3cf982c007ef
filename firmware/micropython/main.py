# Entry point on the board (copy with pfdoa_defs.py, pfdoa_wire.py, pfdoa_anchor.py and
# board_ble.py). Edit the values below for the installation; every anchor on one gateway
# needs its own ANCHOR_ID (0..126).
import board_ble

ANCHOR_ID = 1
UART_ID = 1
UART_BAUD = 115200
UART_PINS = None  # (tx, rx) pin numbers, or None for the port's defaults
CAN_ID = None  # machine.CAN controller id, or None without CAN
CAN_BITRATE = 500000
REPORT_ON_CAN = False  # reports and STATUS on CAN instead of the UART
# Which beacons to follow is the anchor's filter table (our beacon id 0 until the host
# sends FILTER_SETs; kept in pfdoa_flt.bin): `pfdoa anchors` sets it.

board_ble.run(ANCHOR_ID, uart_id=UART_ID, baudrate=UART_BAUD, uart_pins=UART_PINS,
              can_id=CAN_ID, can_bitrate=CAN_BITRATE, report_on_can=REPORT_ON_CAN)
