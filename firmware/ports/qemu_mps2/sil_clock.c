#include "sil_clock.h"

#include "pfdoa_defs.h"
#include "pfdoa_msg.h"

static const uint8_t inject_type[] = { PFDOA_MSG_RADIO_INJECT, PFDOA_MSG_RADIO_INJECT_RAW };

void sil_clock_init(sil_clock_t *clock, uint8_t anchor_id, uint32_t start_ms)
{
    pfdoa_decoder_init(&clock->decoder, inject_type, sizeof inject_type);
    clock->now_ms = start_ms;
    clock->anchor_id = anchor_id;
}

int sil_clock_push(sil_clock_t *clock, uint8_t byte)
{
    pfdoa_frame_t frame;
    if (pfdoa_decoder_push(&clock->decoder, byte, &frame) != 1) {
        return 0;
    }
    if (frame.anchor_id != clock->anchor_id && frame.anchor_id != PFDOA_ANCHOR_BROADCAST) {
        return 0;
    }
    if (frame.type == PFDOA_MSG_RADIO_INJECT_RAW) {
        /* The reception's tick, u32 LE (SPEC 1.7); the core decodes the rest itself. */
        uint32_t tick = 0u;
        for (uint32_t i = 4u; i > 0u; --i) {
            tick = (tick << 8) | frame.payload[PFDOA_MSG_RADIO_INJECT_RAW_OFF_TICK_MS + i - 1u];
        }
        clock->now_ms = tick;
        return 1;
    }
    pfdoa_radio_reading_t reading;
    pfdoa_msg_unpack_radio_inject(frame.payload, &reading);
    clock->now_ms = reading.tick_ms;
    return 1;
}
