/* The host link's framing on the UART (docs/protocol.md, "Framing"; the codes and sizes in
 * the generated wire_codes.h): COBS frames delimited by 0x00, CRC-32 over the body.
 *   link_poll()         decode every byte waiting in the UART; each whole frame goes to
 *                       proto_frame() (proto.c); bad frames are dropped and counted
 *   link_send(...)      one frame: 0x00, COBS(header, payload, CRC), 0x00
 *   crc32(...)          CRC-32 (IEEE 802.3, zlib.crc32's), continued from crc
 */
#ifndef SPRINGTRACK_FW_LINK_H
#define SPRINGTRACK_FW_LINK_H

#include <stdint.h>
#include "wire_codes.h"

typedef struct {
    uint8_t version, type, flags;
    uint16_t seq;
    const uint8_t *header;         /* the 5 header bytes */
    const uint8_t *payload;
    uint32_t len;                  /* payload bytes, without a signature */
    const uint8_t *sig;            /* u64 counter + tag when SIGNED, else 0 */
} frame_t;

/* frames, bytes, crc_errors, cobs_errors, malformed, oversize: wire.FrameReader's; tx */
typedef struct {
    uint32_t frames, bytes, crc_errors, cobs_errors, malformed, oversize;
    uint32_t tx_frames, tx_bytes;
} link_counts_t;

extern link_counts_t link_counts;

void link_init(void);
void link_poll(void);
void link_send(uint8_t version, uint8_t type, uint16_t seq, const uint8_t *payload, uint32_t len);
uint32_t crc32(uint32_t crc, const uint8_t *p, uint32_t n);
void proto_frame(const frame_t *f);          /* proto.c */

#endif
