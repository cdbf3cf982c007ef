/*
 * selftest.c - a port-only image for tests/qemu/test_qemu_port.py: checks the tick, the
 * UART in both directions (every byte value, with the RX ring filling up) and the
 * semihosting exit status, without the anchor core.
 *
 * Protocol: on boot it spins a fixed workload and sends "PORT" + the milliseconds it
 * took (u32 LE; identical from run to run under -icount shift=0) and the anchor id
 * from the semihosting command line (0xFF if none). Then it echoes
 * SELFTEST_ECHO_BYTES received bytes, sends "DONE" and exits with status 3.
 */
#include <stdint.h>

#include "board.h"

#define SELFTEST_ECHO_BYTES 1024u
#define SELFTEST_SPIN       2000000u
#define SELFTEST_EXIT       3

int main(void)
{
    board_init();
    board_tick_start();
    const uint32_t t0 = board_tick_ms();
    for (volatile uint32_t i = 0; i < SELFTEST_SPIN; i = i + 1u) {
    }
    const uint32_t dt = board_tick_ms() - t0;
    const uint8_t banner[9] = { 'P', 'O', 'R', 'T', (uint8_t)dt, (uint8_t)(dt >> 8),
                                (uint8_t)(dt >> 16), (uint8_t)(dt >> 24), (uint8_t)board_param_u32("id", 126u, 0xFFu) };
    board_uart_write(banner, sizeof banner);

    uint32_t echoed = 0u;
    uint8_t buf[64];
    while (echoed < SELFTEST_ECHO_BYTES) {
        const size_t n = board_uart_read(buf, sizeof buf);
        if (n == 0u) {
            board_idle();
            continue;
        }
        board_uart_write(buf, n);
        echoed += (uint32_t)n;
    }
    static const uint8_t done[4] = { 'D', 'O', 'N', 'E' };
    board_uart_write(done, sizeof done);
    return SELFTEST_EXIT;
}
