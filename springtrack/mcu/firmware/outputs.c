/* The frames the firmware sends unasked (docs/protocol.md): TELEMETRY, ENERGIES, its own
 * HEARTBEAT and the NOTICE that the stream ended, to the session while it receives. */
#include "board.h"
#include "engine.h"
#include "fixed_step.h"
#include "link_key.h"
#include "proto.h"

void proto_telemetry(int64_t t, uint32_t energy_bits, const uint8_t *records, uint32_t n,
                     const int16_t *velocity)
{
    buf_t b = proto_out();
    uint32_t i;
    if (!sess.session || (LINK_KEY_LEN && !sess.authenticated))
        return;                          /* nobody to send it to */
    b_u64(&b, (uint64_t)t);
    b_u16(&b, eng.generation);
    b_u32(&b, energy_bits);
    b_u8(&b, n);
    b_bytes(&b, records, n * WIRE_TELE_TRACKER);
    if (velocity) {                      /* wire.VELOCITY_TAG, then vx, vy per tracker */
        b_u8(&b, WIRE_VELOCITY_TAG);
        for (i = 0; i < 2 * n; i++)
            b_u16(&b, (uint16_t)velocity[i]);
    }
    sess.telemetry++;
    proto_send(MSG_TELEMETRY, b.p, b.n);
}

/* a session receives telemetry, reports and heartbeats (on a keyed link once authentic) */
int proto_receiving(void)
{
    return sess.session && (!LINK_KEY_LEN || sess.authenticated);
}

/* ENERGIES: t, the criterion's kind, each connection's energy as float32 bits */
void proto_energies(int64_t t, uint32_t kind, const uint32_t *bits, uint32_t n)
{
    buf_t b = proto_out();
    uint32_t k;
    b_u64(&b, (uint64_t)t);
    b_u8(&b, kind);
    b_u16(&b, n);
    for (k = 0; k < n; k++)
        b_u32(&b, bits[k]);
    proto_send(MSG_ENERGIES, b.p, b.n);
}

/* the firmware's own HEARTBEAT once a second of its clock (SysTick, BOARD_CLOCK_HZ): its
   uptime and link counters (wire.HEARTBEAT_FIELDS); polled from the main loop, more often
   than SysTick's 24 bits wrap */
void proto_tick(void)
{
    static uint64_t ticks, next = BOARD_CLOCK_HZ;
    static uint32_t last;
    uint32_t now = board_ticks(), r;
    buf_t b = proto_out();
    ticks += (last - now) & 0xFFFFFFu;   /* SysTick counts down */
    last = now;
    if (ticks < next)
        return;
    next = ticks + BOARD_CLOCK_HZ;
    if (!proto_receiving())
        return;
    b_u64(&b, fx_udiv64(ticks, BOARD_CLOCK_HZ / 1000000u, &r));
    b_u32(&b, link_counts.frames);
    b_u32(&b, link_counts.crc_errors + link_counts.cobs_errors + link_counts.malformed
              + link_counts.oversize);
    b_u32(&b, sess.rx_lost);
    b_u32(&b, link_counts.tx_frames);
    b_u32(&b, 0);                        /* tx_dropped: the UART waits, nothing is dropped */
    proto_send(MSG_HEARTBEAT, b.p, b.n);
}

void proto_stream_ended(void)
{
    static const char text[] = "the source has no more data; the loop is idle (START replays it)";
    buf_t b = proto_out();
    if (!sess.session || (LINK_KEY_LEN && !sess.authenticated))
        return;
    b_u8(&b, NOTICE_STREAM_ENDED);
    b_u16(&b, sizeof text - 1);
    b_str(&b, text);
    proto_send(MSG_NOTICE, b.p, b.n);
}

