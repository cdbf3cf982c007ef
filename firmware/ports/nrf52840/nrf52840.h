/*
 * nrf52840.h - the few nRF52840 peripheral registers this port uses, written from the
 * nRF52840 Product Specification v1.7 (PS), each block beside the chapter it comes from.
 * No vendor MDK: only the registers and bit fields the drivers touch.
 *
 * Every block is a struct laid out at the PS's register offsets (the static assertions at
 * the end check each offset we use). A driver reaches a block through NRF_<NAME>, which is
 * the peripheral's base address on the chip, or, in a host test build (-DNRF_FAKE), a RAM
 * struct the test drives (tests/fake_nrf.h): events raised, packets placed in RAM,
 * interrupt handlers called.
 */
#ifndef NRF52840_H
#define NRF52840_H

#include <stddef.h>
#include <stdint.h>

typedef volatile uint32_t nrf_reg_t;

/* ---- CLOCK (PS v1.7, chapter "CLOCK - Clock control", Registers; base 0x40000000) ---- */
typedef struct {
    nrf_reg_t TASKS_HFCLKSTART;   /* 0x000 */
    nrf_reg_t TASKS_HFCLKSTOP;    /* 0x004 */
    nrf_reg_t TASKS_LFCLKSTART;   /* 0x008 */
    nrf_reg_t TASKS_LFCLKSTOP;    /* 0x00C */
    nrf_reg_t TASKS_CAL;          /* 0x010 */
    nrf_reg_t rsvd0[59];
    nrf_reg_t EVENTS_HFCLKSTARTED; /* 0x100 */
    nrf_reg_t EVENTS_LFCLKSTARTED; /* 0x104 */
    nrf_reg_t rsvd1;
    nrf_reg_t EVENTS_DONE;        /* 0x10C: LFRC calibration done */
    nrf_reg_t rsvd2[191];
    nrf_reg_t HFCLKSTAT;          /* 0x40C */
    nrf_reg_t rsvd3[2];
    nrf_reg_t LFCLKSTAT;          /* 0x418 */
    nrf_reg_t rsvd4[63];
    nrf_reg_t LFCLKSRC;           /* 0x518 */
} nrf_clock_t;
#define NRF_CLOCK_STAT_SRC_MASK  0x3u
#define NRF_CLOCK_STAT_RUNNING   (1u << 16)
#define NRF_CLOCK_LFCLKSRC_RC    0u
#define NRF_CLOCK_LFCLKSRC_XTAL  1u
#define NRF_CLOCK_HFCLKSTAT_XTAL 1u

/* ---- RTC (PS v1.7, chapter "RTC - Real-time counter", Registers; RTC1 at 0x40011000) ---- */
typedef struct {
    nrf_reg_t TASKS_START;        /* 0x000 */
    nrf_reg_t TASKS_STOP;         /* 0x004 */
    nrf_reg_t TASKS_CLEAR;        /* 0x008 */
    nrf_reg_t TASKS_TRIGOVRFLW;   /* 0x00C */
    nrf_reg_t rsvd0[60];
    nrf_reg_t EVENTS_TICK;        /* 0x100 */
    nrf_reg_t EVENTS_OVRFLW;      /* 0x104 */
    nrf_reg_t rsvd1[14];
    nrf_reg_t EVENTS_COMPARE[4];  /* 0x140 */
    nrf_reg_t rsvd2[109];
    nrf_reg_t INTENSET;           /* 0x304 */
    nrf_reg_t INTENCLR;           /* 0x308 */
    nrf_reg_t rsvd3[13];
    nrf_reg_t EVTEN;              /* 0x340 */
    nrf_reg_t rsvd4[112];
    nrf_reg_t COUNTER;            /* 0x504: 24 bits */
    nrf_reg_t PRESCALER;          /* 0x508: f = 32768 / (PRESCALER + 1) */
    nrf_reg_t rsvd5[13];
    nrf_reg_t CC[4];              /* 0x540 */
} nrf_rtc_t;
#define NRF_RTC_INT_OVRFLW       (1u << 1)
#define NRF_RTC_INT_COMPARE(n)   (1u << (16u + (n)))
#define NRF_RTC_COUNTER_MASK     0x00FFFFFFu

/* ---- UARTE (PS v1.7, chapter "UARTE - Universal asynchronous receiver/transmitter with
 *      EasyDMA", Registers; UARTE0 at 0x40002000) ---- */
typedef struct {
    nrf_reg_t TASKS_STARTRX;      /* 0x000 */
    nrf_reg_t TASKS_STOPRX;       /* 0x004 */
    nrf_reg_t TASKS_STARTTX;      /* 0x008 */
    nrf_reg_t TASKS_STOPTX;       /* 0x00C */
    nrf_reg_t rsvd0[7];
    nrf_reg_t TASKS_FLUSHRX;      /* 0x02C */
    nrf_reg_t rsvd1[52];
    nrf_reg_t EVENTS_CTS;         /* 0x100 */
    nrf_reg_t EVENTS_NCTS;        /* 0x104 */
    nrf_reg_t EVENTS_RXDRDY;      /* 0x108 */
    nrf_reg_t rsvd2;
    nrf_reg_t EVENTS_ENDRX;       /* 0x110 */
    nrf_reg_t rsvd3[2];
    nrf_reg_t EVENTS_TXDRDY;      /* 0x11C */
    nrf_reg_t EVENTS_ENDTX;       /* 0x120 */
    nrf_reg_t EVENTS_ERROR;       /* 0x124 */
    nrf_reg_t rsvd4[7];
    nrf_reg_t EVENTS_RXTO;        /* 0x144 */
    nrf_reg_t rsvd5;
    nrf_reg_t EVENTS_RXSTARTED;   /* 0x14C */
    nrf_reg_t EVENTS_TXSTARTED;   /* 0x150 */
    nrf_reg_t rsvd6;
    nrf_reg_t EVENTS_TXSTOPPED;   /* 0x158 */
    nrf_reg_t rsvd7[41];
    nrf_reg_t SHORTS;             /* 0x200 */
    nrf_reg_t rsvd8[63];
    nrf_reg_t INTEN;              /* 0x300 */
    nrf_reg_t INTENSET;           /* 0x304 */
    nrf_reg_t INTENCLR;           /* 0x308 */
    nrf_reg_t rsvd9[93];
    nrf_reg_t ERRORSRC;           /* 0x480: write 1 to clear */
    nrf_reg_t rsvd10[31];
    nrf_reg_t ENABLE;             /* 0x500 */
    nrf_reg_t rsvd11;
    nrf_reg_t PSEL_RTS;           /* 0x508 */
    nrf_reg_t PSEL_TXD;           /* 0x50C */
    nrf_reg_t PSEL_CTS;           /* 0x510 */
    nrf_reg_t PSEL_RXD;           /* 0x514 */
    nrf_reg_t rsvd12[3];
    nrf_reg_t BAUDRATE;           /* 0x524 */
    nrf_reg_t rsvd13[3];
    nrf_reg_t RXD_PTR;            /* 0x534 */
    nrf_reg_t RXD_MAXCNT;         /* 0x538 */
    nrf_reg_t RXD_AMOUNT;         /* 0x53C */
    nrf_reg_t rsvd14;
    nrf_reg_t TXD_PTR;            /* 0x544 */
    nrf_reg_t TXD_MAXCNT;         /* 0x548 */
    nrf_reg_t TXD_AMOUNT;         /* 0x54C */
    nrf_reg_t rsvd15[7];
    nrf_reg_t CONFIG;             /* 0x56C: HWFC bit 0, PARITY bits 1-3, STOP bit 4 */
} nrf_uarte_t;
#define NRF_UARTE_INT_RXDRDY     (1u << 2)
#define NRF_UARTE_INT_ENDRX      (1u << 4)
#define NRF_UARTE_INT_ENDTX      (1u << 8)
#define NRF_UARTE_INT_ERROR      (1u << 9)
#define NRF_UARTE_INT_RXTO       (1u << 17)
#define NRF_UARTE_ENABLE         8u
#define NRF_UARTE_BAUD_115200    0x01D60000u /* BAUDRATE table: 115942 baud actual */
#define NRF_PSEL_DISCONNECTED    0xFFFFFFFFu /* PSEL.xxx: CONNECT (bit 31) = 1 */

/* ---- RADIO (PS v1.7 §6.20 "RADIO - 2.4 GHz radio", Registers; base 0x40001000) ---- */
typedef struct {
    nrf_reg_t TASKS_TXEN;         /* 0x000 */
    nrf_reg_t TASKS_RXEN;         /* 0x004 */
    nrf_reg_t TASKS_START;        /* 0x008 */
    nrf_reg_t TASKS_STOP;         /* 0x00C */
    nrf_reg_t TASKS_DISABLE;      /* 0x010 */
    nrf_reg_t TASKS_RSSISTART;    /* 0x014 */
    nrf_reg_t TASKS_RSSISTOP;     /* 0x018 */
    nrf_reg_t rsvd0[57];
    nrf_reg_t EVENTS_READY;       /* 0x100 */
    nrf_reg_t EVENTS_ADDRESS;     /* 0x104: address (BLE) / SFD (802.15.4) received */
    nrf_reg_t EVENTS_PAYLOAD;     /* 0x108 */
    nrf_reg_t EVENTS_END;         /* 0x10C: packet received and in RAM */
    nrf_reg_t EVENTS_DISABLED;    /* 0x110 */
    nrf_reg_t rsvd1[2];
    nrf_reg_t EVENTS_RSSIEND;     /* 0x11C: RSSISAMPLE holds a new sample */
    nrf_reg_t rsvd2[56];
    nrf_reg_t SHORTS;             /* 0x200 */
    nrf_reg_t rsvd3[64];
    nrf_reg_t INTENSET;           /* 0x304 */
    nrf_reg_t INTENCLR;           /* 0x308 */
    nrf_reg_t rsvd4[61];
    nrf_reg_t CRCSTATUS;          /* 0x400: 1 = CRC ok */
    nrf_reg_t rsvd5[64];
    nrf_reg_t PACKETPTR;          /* 0x504: EasyDMA RAM address of the packet */
    nrf_reg_t FREQUENCY;          /* 0x508: 2400 + FREQUENCY MHz (MAP = 0) */
    nrf_reg_t TXPOWER;            /* 0x50C */
    nrf_reg_t MODE;               /* 0x510 */
    nrf_reg_t PCNF0;              /* 0x514 */
    nrf_reg_t PCNF1;              /* 0x518 */
    nrf_reg_t BASE0;              /* 0x51C */
    nrf_reg_t BASE1;              /* 0x520 */
    nrf_reg_t PREFIX0;            /* 0x524 */
    nrf_reg_t PREFIX1;            /* 0x528 */
    nrf_reg_t TXADDRESS;          /* 0x52C */
    nrf_reg_t RXADDRESSES;        /* 0x530 */
    nrf_reg_t CRCCNF;             /* 0x534 */
    nrf_reg_t CRCPOLY;            /* 0x538 */
    nrf_reg_t CRCINIT;            /* 0x53C */
    nrf_reg_t rsvd6[2];
    nrf_reg_t RSSISAMPLE;         /* 0x548: RSSI = -RSSISAMPLE dBm */
    nrf_reg_t rsvd7;
    nrf_reg_t STATE;              /* 0x550 */
    nrf_reg_t DATAWHITEIV;        /* 0x554 */
    nrf_reg_t rsvd8[62];
    nrf_reg_t MODECNF0;           /* 0x650: RU bit 0 = fast ramp-up */
    nrf_reg_t rsvd9[3];
    nrf_reg_t SFD;                /* 0x660 */
    nrf_reg_t rsvd10[614];
    nrf_reg_t POWER;              /* 0xFFC */
} nrf_radio_t;
/* SHORTS */
#define NRF_RADIO_SHORT_READY_START       (1u << 0)
#define NRF_RADIO_SHORT_END_DISABLE       (1u << 1)
#define NRF_RADIO_SHORT_ADDRESS_RSSISTART (1u << 4)
#define NRF_RADIO_SHORT_DISABLED_RSSISTOP (1u << 8)
/* INTENSET/INTENCLR */
#define NRF_RADIO_INT_DISABLED            (1u << 4)
/* MODE */
#define NRF_RADIO_MODE_BLE_1MBIT          3u
#define NRF_RADIO_MODE_IEEE802154_250KBIT 15u
/* PCNF0: LFLEN bits 0-3, S0LEN bit 8, S1LEN bits 16-19, PLEN bits 24-25, CRCINC bit 26 */
#define NRF_RADIO_PCNF0_LFLEN(n)          ((uint32_t)(n) << 0)
#define NRF_RADIO_PCNF0_S0LEN(n)          ((uint32_t)(n) << 8)
#define NRF_RADIO_PCNF0_PLEN_8BIT         (0u << 24)
#define NRF_RADIO_PCNF0_PLEN_32BIT_ZERO   (2u << 24)
#define NRF_RADIO_PCNF0_CRCINC            (1u << 26)
/* PCNF1: MAXLEN bits 0-7, STATLEN bits 8-15, BALEN bits 16-18, ENDIAN bit 24, WHITEEN bit 25 */
#define NRF_RADIO_PCNF1_MAXLEN(n)         ((uint32_t)(n) << 0)
#define NRF_RADIO_PCNF1_BALEN(n)          ((uint32_t)(n) << 16)
#define NRF_RADIO_PCNF1_WHITEEN           (1u << 25)
/* CRCCNF: LEN bits 0-1, SKIPADDR bits 8-9 */
#define NRF_RADIO_CRCCNF_LEN(n)           ((uint32_t)(n) << 0)
#define NRF_RADIO_CRCCNF_SKIPADDR_SKIP    (1u << 8)
#define NRF_RADIO_CRCCNF_SKIPADDR_IEEE    (2u << 8)
/* STATE */
#define NRF_RADIO_STATE_DISABLED          0u
/* RSSISAMPLE: 7 bits, RSSI = -RSSISAMPLE dBm */
#define NRF_RADIO_RSSISAMPLE_MASK         0x7Fu
#define NRF_RADIO_MODECNF0_RU_FAST        1u

/* ---- SPIM (PS v1.7, chapter "SPIM - Serial peripheral interface master with EasyDMA",
 *      Registers; SPIM2 at 0x40023000) ---- */
typedef struct {
    nrf_reg_t rsvd0[4];
    nrf_reg_t TASKS_START;        /* 0x010 */
    nrf_reg_t TASKS_STOP;         /* 0x014 */
    nrf_reg_t rsvd1[59];
    nrf_reg_t EVENTS_STOPPED;     /* 0x104 */
    nrf_reg_t rsvd2[4];
    nrf_reg_t EVENTS_END;         /* 0x118: both buffers done */
    nrf_reg_t rsvd3[249];
    nrf_reg_t ENABLE;             /* 0x500 */
    nrf_reg_t rsvd4;
    nrf_reg_t PSEL_SCK;           /* 0x508 */
    nrf_reg_t PSEL_MOSI;          /* 0x50C */
    nrf_reg_t PSEL_MISO;          /* 0x510 */
    nrf_reg_t rsvd5[4];
    nrf_reg_t FREQUENCY;          /* 0x524 */
    nrf_reg_t rsvd6[3];
    nrf_reg_t RXD_PTR;            /* 0x534 */
    nrf_reg_t RXD_MAXCNT;         /* 0x538 */
    nrf_reg_t RXD_AMOUNT;         /* 0x53C */
    nrf_reg_t RXD_LIST;           /* 0x540 */
    nrf_reg_t TXD_PTR;            /* 0x544 */
    nrf_reg_t TXD_MAXCNT;         /* 0x548 */
    nrf_reg_t TXD_AMOUNT;         /* 0x54C */
    nrf_reg_t TXD_LIST;           /* 0x550 */
    nrf_reg_t CONFIG;             /* 0x554: ORDER bit 0, CPHA bit 1, CPOL bit 2 */
    nrf_reg_t rsvd7[26];
    nrf_reg_t ORC;                /* 0x5C0: byte clocked out after TXD.MAXCNT */
} nrf_spim_t;
#define NRF_SPIM_ENABLE          7u
#define NRF_SPIM_FREQ_4M         0x40000000u
#define NRF_SPIM_CONFIG_MODE0    0u /* MSB first, CPHA leading, CPOL active high */

/* ---- GPIO (PS v1.7, chapter "GPIO - General purpose input/output", Registers;
 *      P0 at 0x50000000, P1 at 0x50000300) ---- */
typedef struct {
    nrf_reg_t rsvd0[321];
    nrf_reg_t OUT;                /* 0x504 */
    nrf_reg_t OUTSET;             /* 0x508 */
    nrf_reg_t OUTCLR;             /* 0x50C */
    nrf_reg_t IN;                 /* 0x510 */
    nrf_reg_t DIR;                /* 0x514 */
    nrf_reg_t DIRSET;             /* 0x518 */
    nrf_reg_t DIRCLR;             /* 0x51C */
    nrf_reg_t rsvd1[120];
    nrf_reg_t PIN_CNF[32];        /* 0x700 */
} nrf_gpio_t;
/* PIN_CNF: DIR bit 0, INPUT bit 1 (0 = connect), PULL bits 2-3 (3 = up) */
#define NRF_GPIO_CNF_OUTPUT      1u
#define NRF_GPIO_CNF_INPUT       0u
#define NRF_GPIO_CNF_PULLUP      (3u << 2)
/* PSEL registers: PIN bits 0-4, PORT bit 5 */
#define NRF_PSEL(port, pin)      (((uint32_t)(port) << 5) | (uint32_t)(pin))

/* ---- GPIOTE (PS v1.7, chapter "GPIOTE - GPIO tasks and events", Registers; 0x40006000) ---- */
typedef struct {
    nrf_reg_t rsvd0[64];
    nrf_reg_t EVENTS_IN[8];       /* 0x100 */
    nrf_reg_t rsvd1[121];
    nrf_reg_t INTENSET;           /* 0x304 */
    nrf_reg_t INTENCLR;           /* 0x308 */
    nrf_reg_t rsvd2[129];
    nrf_reg_t CONFIG[8];          /* 0x510 */
} nrf_gpiote_t;
/* CONFIG: MODE bits 0-1 (1 = event), PSEL bits 8-12, PORT bit 13, POLARITY bits 16-17 */
#define NRF_GPIOTE_CONFIG_EVENT_HITOLO(port, pin) \
    (1u | ((uint32_t)(pin) << 8) | ((uint32_t)(port) << 13) | (2u << 16))

/* ---- NVMC (PS v1.7, chapter "NVMC - Non-volatile memory controller", Registers;
 *      0x4001E000). Flash pages are 4 KB; a word is written once between erases here. ---- */
typedef struct {
    nrf_reg_t rsvd0[256];
    nrf_reg_t READY;              /* 0x400 */
    nrf_reg_t rsvd1[64];
    nrf_reg_t CONFIG;             /* 0x504: 0 read, 1 write, 2 erase enabled */
    nrf_reg_t ERASEPAGE;          /* 0x508: write the page's address */
} nrf_nvmc_t;
#define NRF_NVMC_CONFIG_REN      0u
#define NRF_NVMC_CONFIG_WEN      1u
#define NRF_NVMC_CONFIG_EEN      2u
#define NRF_FLASH_PAGE_SIZE      4096u
/* The store's pages (flash_store.c): page 0 is the last flash page (0xFF000), page 1 the one
 * before it (0xFE000); link.ld keeps the image out of both. */
#define NRF_STORE_PAGES          2u
#define NRF_STORE_PAGE0_ADDR     0x000FF000u

/* Interrupt numbers (PS v1.7, chapter "Memory", Peripheral instantiation table: ID = IRQ). */
#define NRF_IRQ_POWER_CLOCK      0u
#define NRF_IRQ_RADIO            1u
#define NRF_IRQ_UARTE0           2u
#define NRF_IRQ_GPIOTE           6u
#define NRF_IRQ_RTC1             17u
#define NRF_IRQ_SPIM2            35u
#define NRF_IRQ_COUNT            48u

/* UICR.CUSTOMER[0] (PS v1.7, chapter "UICR - User information configuration registers":
 * 0x10001080): the anchor id when programmed to 0..126 (erased flash reads 0xFFFFFFFF). */

#ifdef NRF_FAKE
/* Host test build: each block is RAM the test drives (tests/fake_nrf.c). */
extern nrf_clock_t nrf_fake_clock;
extern nrf_rtc_t nrf_fake_rtc1;
extern nrf_uarte_t nrf_fake_uarte0;
extern nrf_radio_t nrf_fake_radio;
extern nrf_spim_t nrf_fake_spim2;
extern nrf_gpio_t nrf_fake_p0;
extern nrf_gpio_t nrf_fake_p1;
extern nrf_gpiote_t nrf_fake_gpiote;
extern nrf_nvmc_t nrf_fake_nvmc;
extern uint32_t nrf_fake_uicr_customer0;
extern uint32_t nrf_fake_store_pages[NRF_STORE_PAGES][NRF_FLASH_PAGE_SIZE / 4u];
#define NRF_CLOCK   (&nrf_fake_clock)
#define NRF_RTC1    (&nrf_fake_rtc1)
#define NRF_UARTE0  (&nrf_fake_uarte0)
#define NRF_RADIO   (&nrf_fake_radio)
#define NRF_SPIM2   (&nrf_fake_spim2)
#define NRF_P0      (&nrf_fake_p0)
#define NRF_P1      (&nrf_fake_p1)
#define NRF_GPIOTE  (&nrf_fake_gpiote)
#define NRF_NVMC    (&nrf_fake_nvmc)
#define NRF_UICR_CUSTOMER0 (nrf_fake_uicr_customer0)
#define NRF_STORE_PAGE(n)  ((const volatile uint32_t *)nrf_fake_store_pages[(n)])
/* EasyDMA takes 32-bit RAM addresses; host pointers are wider, so the fake hands out
 * 32-bit handles and maps them back (nrf_fake_dma_ptr). Flash words go through the fake's
 * model of the NVMC (write only when enabled, bits only 1 -> 0). */
uint32_t nrf_fake_dma_addr(const volatile void *p);
void nrf_fake_flash_write(const volatile uint32_t *addr, uint32_t word);
/* Called inside every busy-wait loop: the fake's hardware reacts to the tasks written. */
void nrf_fake_spin(void);
#define NRF_DMA_ADDR(p)             nrf_fake_dma_addr(p)
#define NRF_FLASH_WRITE(addr, word) nrf_fake_flash_write((addr), (word))
#define NRF_SPIN()                  nrf_fake_spin()
#else
#define NRF_CLOCK   ((nrf_clock_t *)0x40000000u)
#define NRF_RADIO   ((nrf_radio_t *)0x40001000u)
#define NRF_UARTE0  ((nrf_uarte_t *)0x40002000u)
#define NRF_GPIOTE  ((nrf_gpiote_t *)0x40006000u)
#define NRF_RTC1    ((nrf_rtc_t *)0x40011000u)
#define NRF_NVMC    ((nrf_nvmc_t *)0x4001E000u)
#define NRF_SPIM2   ((nrf_spim_t *)0x40023000u)
#define NRF_P0      ((nrf_gpio_t *)0x50000000u)
#define NRF_P1      ((nrf_gpio_t *)0x50000300u)
#define NRF_UICR_CUSTOMER0 (*(const volatile uint32_t *)0x10001080u)
#define NRF_STORE_PAGE(n)  ((const volatile uint32_t *)(uintptr_t)(NRF_STORE_PAGE0_ADDR - (n) * NRF_FLASH_PAGE_SIZE))
#define NRF_DMA_ADDR(p)             ((uint32_t)(uintptr_t)(p))
#define NRF_FLASH_WRITE(addr, word) (*(volatile uint32_t *)(uintptr_t)(addr) = (word))
#define NRF_SPIN()                  ((void)0)
#endif

/* Offsets checked against the PS register tables (C99: a negative array size fails). */
#define NRF_OFFSET_IS(type, field, off) \
    typedef char nrf_offset_##type##_##field[(offsetof(type, field) == (off)) ? 1 : -1]
NRF_OFFSET_IS(nrf_clock_t, EVENTS_HFCLKSTARTED, 0x100);
NRF_OFFSET_IS(nrf_clock_t, EVENTS_DONE, 0x10C);
NRF_OFFSET_IS(nrf_clock_t, HFCLKSTAT, 0x40C);
NRF_OFFSET_IS(nrf_clock_t, LFCLKSTAT, 0x418);
NRF_OFFSET_IS(nrf_clock_t, LFCLKSRC, 0x518);
NRF_OFFSET_IS(nrf_rtc_t, EVENTS_OVRFLW, 0x104);
NRF_OFFSET_IS(nrf_rtc_t, EVENTS_COMPARE, 0x140);
NRF_OFFSET_IS(nrf_rtc_t, INTENSET, 0x304);
NRF_OFFSET_IS(nrf_rtc_t, EVTEN, 0x340);
NRF_OFFSET_IS(nrf_rtc_t, COUNTER, 0x504);
NRF_OFFSET_IS(nrf_rtc_t, CC, 0x540);
NRF_OFFSET_IS(nrf_uarte_t, TASKS_FLUSHRX, 0x02C);
NRF_OFFSET_IS(nrf_uarte_t, EVENTS_RXDRDY, 0x108);
NRF_OFFSET_IS(nrf_uarte_t, EVENTS_ENDRX, 0x110);
NRF_OFFSET_IS(nrf_uarte_t, EVENTS_ENDTX, 0x120);
NRF_OFFSET_IS(nrf_uarte_t, EVENTS_ERROR, 0x124);
NRF_OFFSET_IS(nrf_uarte_t, EVENTS_RXTO, 0x144);
NRF_OFFSET_IS(nrf_uarte_t, EVENTS_TXSTOPPED, 0x158);
NRF_OFFSET_IS(nrf_uarte_t, SHORTS, 0x200);
NRF_OFFSET_IS(nrf_uarte_t, INTENSET, 0x304);
NRF_OFFSET_IS(nrf_uarte_t, ERRORSRC, 0x480);
NRF_OFFSET_IS(nrf_uarte_t, ENABLE, 0x500);
NRF_OFFSET_IS(nrf_uarte_t, PSEL_TXD, 0x50C);
NRF_OFFSET_IS(nrf_uarte_t, PSEL_RXD, 0x514);
NRF_OFFSET_IS(nrf_uarte_t, BAUDRATE, 0x524);
NRF_OFFSET_IS(nrf_uarte_t, RXD_PTR, 0x534);
NRF_OFFSET_IS(nrf_uarte_t, TXD_PTR, 0x544);
NRF_OFFSET_IS(nrf_uarte_t, TXD_AMOUNT, 0x54C);
NRF_OFFSET_IS(nrf_uarte_t, CONFIG, 0x56C);
NRF_OFFSET_IS(nrf_radio_t, TASKS_RSSISTOP, 0x018);
NRF_OFFSET_IS(nrf_radio_t, EVENTS_READY, 0x100);
NRF_OFFSET_IS(nrf_radio_t, EVENTS_DISABLED, 0x110);
NRF_OFFSET_IS(nrf_radio_t, EVENTS_RSSIEND, 0x11C);
NRF_OFFSET_IS(nrf_radio_t, SHORTS, 0x200);
NRF_OFFSET_IS(nrf_radio_t, INTENSET, 0x304);
NRF_OFFSET_IS(nrf_radio_t, CRCSTATUS, 0x400);
NRF_OFFSET_IS(nrf_radio_t, PACKETPTR, 0x504);
NRF_OFFSET_IS(nrf_radio_t, CRCINIT, 0x53C);
NRF_OFFSET_IS(nrf_radio_t, RSSISAMPLE, 0x548);
NRF_OFFSET_IS(nrf_radio_t, STATE, 0x550);
NRF_OFFSET_IS(nrf_radio_t, DATAWHITEIV, 0x554);
NRF_OFFSET_IS(nrf_radio_t, MODECNF0, 0x650);
NRF_OFFSET_IS(nrf_radio_t, SFD, 0x660);
NRF_OFFSET_IS(nrf_radio_t, POWER, 0xFFC);
NRF_OFFSET_IS(nrf_spim_t, TASKS_START, 0x010);
NRF_OFFSET_IS(nrf_spim_t, EVENTS_STOPPED, 0x104);
NRF_OFFSET_IS(nrf_spim_t, EVENTS_END, 0x118);
NRF_OFFSET_IS(nrf_spim_t, ENABLE, 0x500);
NRF_OFFSET_IS(nrf_spim_t, PSEL_MISO, 0x510);
NRF_OFFSET_IS(nrf_spim_t, FREQUENCY, 0x524);
NRF_OFFSET_IS(nrf_spim_t, RXD_PTR, 0x534);
NRF_OFFSET_IS(nrf_spim_t, TXD_PTR, 0x544);
NRF_OFFSET_IS(nrf_spim_t, CONFIG, 0x554);
NRF_OFFSET_IS(nrf_spim_t, ORC, 0x5C0);
NRF_OFFSET_IS(nrf_gpio_t, OUT, 0x504);
NRF_OFFSET_IS(nrf_gpio_t, IN, 0x510);
NRF_OFFSET_IS(nrf_gpio_t, DIRCLR, 0x51C);
NRF_OFFSET_IS(nrf_gpio_t, PIN_CNF, 0x700);
NRF_OFFSET_IS(nrf_gpiote_t, EVENTS_IN, 0x100);
NRF_OFFSET_IS(nrf_gpiote_t, INTENSET, 0x304);
NRF_OFFSET_IS(nrf_gpiote_t, CONFIG, 0x510);
NRF_OFFSET_IS(nrf_nvmc_t, READY, 0x400);
NRF_OFFSET_IS(nrf_nvmc_t, CONFIG, 0x504);
NRF_OFFSET_IS(nrf_nvmc_t, ERASEPAGE, 0x508);

#endif /* NRF52840_H */
