/* The firmware image's main loop: the host link (link.c, proto.c) and the tracking loop
 * (engine.c) in turn, polled, on one core without interrupts: every byte waiting from the
 * host is handled between two batches of events, so a command takes effect between two
 * events (as firmware_sim applies updates), and telemetry leaves as it is sampled. */
#include "engine.h"
#include "link.h"

void proto_init(void);
void proto_tick(void);

void fw_main(void)
{
    engine_init();
    proto_init();
    link_init();
    for (;;) {
        link_poll();
        engine_work();
        proto_tick();
    }
}
