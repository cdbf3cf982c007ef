/*
 * main.c - the pfdoa anchor on the nRF52840: start-up, then the main loop that feeds the
 * core and sleeps between events (app.h).
 */
#include "app.h"

int main(void)
{
    (void)app_init(); /* a failed part is reported by its absence (no radio, no link) */
    for (;;) {
        app_step();
        app_idle();
    }
}
