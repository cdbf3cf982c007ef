/*
 * main_beacon.c - the robot's authenticated beacon on the nRF52840 (beacon_app.h).
 */
#include "beacon_app.h"

int main(void)
{
    (void)beacon_app_init(); /* without the crystal it still answers on the UART */
    for (;;) {
        beacon_app_step();
        beacon_app_idle();
    }
}
