/*
 * board.h - the nRF52840 DK (PCA10056) as an anchor: pins and build-time choices.
 *
 * Build options (-D on the compiler command line; the Makefile passes them):
 *   NRF_LINK_CAN=1            host link through an MCP2515 instead of the UART (default 0)
 *   NRF_CAN_OSC_HZ=8000000    the MCP2515's crystal (8 or 16 MHz modules)
 *   NRF_CAN_BITRATE=500000    125000, 250000, 500000, 1000000 (1 Mbit/s needs 16 MHz)
 *   NRF_IEEE802154_CHANNEL=N  listen to IEEE 802.15.4 channel N (11..26) instead of BLE
 *   NRF_ANCHOR_ID=N           anchor id when UICR.CUSTOMER[0] is not programmed (default 1)
 */
#ifndef NRF_BOARD_H
#define NRF_BOARD_H

#include "nrf52840.h"

#ifndef NRF_LINK_CAN
#define NRF_LINK_CAN 0
#endif
#ifndef NRF_CAN_OSC_HZ
#define NRF_CAN_OSC_HZ 8000000u
#endif
#ifndef NRF_CAN_BITRATE
#define NRF_CAN_BITRATE 500000u
#endif
#ifndef NRF_IEEE802154_CHANNEL
#define NRF_IEEE802154_CHANNEL 0 /* 0: BLE advertising */
#endif
#ifndef NRF_ANCHOR_ID
#define NRF_ANCHOR_ID 1u
#endif

/* UARTE0 to the interface MCU's virtual COM port (DK user guide: P0.06 TXD, P0.08 RXD;
 * RTS P0.05 / CTS P0.07 are not used). */
#define BOARD_UART_TXD   NRF_PSEL(0, 6)
#define BOARD_UART_RXD   NRF_PSEL(0, 8)

/* SPIM2 to the MCP2515 on the DK's Arduino-header SPI positions (D13 SCK, D11 MOSI,
 * D12 MISO, D10 CS) and D9 for its INT output. */
#define BOARD_SPI_SCK    NRF_PSEL(1, 15)
#define BOARD_SPI_MOSI   NRF_PSEL(1, 13)
#define BOARD_SPI_MISO   NRF_PSEL(1, 14)
#define BOARD_CAN_CS_PORT NRF_P1
#define BOARD_CAN_CS_PIN 12u
#define BOARD_CAN_INT_PORT NRF_P1
#define BOARD_CAN_INT_PORTNUM 1u
#define BOARD_CAN_INT_PIN 11u

/* Interrupt priorities (0 highest of 8): RADIO and RTC1 share one so the radio's
 * interrupt and the hop timer never preempt each other. */
#define BOARD_PRIO_RADIO 1u
#define BOARD_PRIO_RTC   1u
#define BOARD_PRIO_LINK  2u

#endif /* NRF_BOARD_H */
