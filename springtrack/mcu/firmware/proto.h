/* What the host link's files share (proto.c: the state machine and its replies;
 * outputs.c: the frames the firmware sends unasked; params.c: PARAM_SET by name). */
#ifndef SPRINGTRACK_FW_PROTO_H
#define SPRINGTRACK_FW_PROTO_H

#include <stdint.h>
#include "link.h"
#include "text.h"

typedef struct {
    uint8_t session, role, authenticated;
    uint64_t last_counter;               /* the highest signature counter accepted */
    uint32_t auth_unsigned, auth_bad_tag, auth_replay, sessions;
    uint32_t hello_seq, hello_crc;       /* the HELLO that opened the session */
    uint16_t tx_seq;
    int32_t rx_last;                     /* -1: expect anything */
    uint8_t nonce[WIRE_NONCE_LEN];
    uint32_t rx_lost, acks, nacks, forbidden, retries, version_refused, updates_rejected;
    uint32_t param_ticks;                /* SysTick ticks of the last PARAM_SET's words */
    uint32_t telemetry;
} proto_session_t;

extern proto_session_t sess;

void proto_send(uint8_t type, const uint8_t *p, uint32_t n);   /* the next sequence number */
buf_t proto_out(void);                   /* the payload buffer (one frame at a time) */
buf_t proto_why(void);                   /* a NACK's reason buffer */
void proto_ack(const frame_t *f, uint32_t value);
void proto_nack(const frame_t *f, uint8_t version, uint8_t code, const buf_t *why);
void proto_nack_text(const frame_t *f, uint8_t code, const char *text);
/* NACK internal for words the checks passed but the kernel refused (a defect if it happens) */
void proto_nack_kernel_refused(const frame_t *f, const char *what, int32_t rc);
void proto_applied(const frame_t *f);   /* a new generation: ACK with it, then APPLIED */

/* the committed parameters: their kernel words (0 once an upload began overwriting them)
   and their key/value list (what PARAM_GET answers; *n its length, which may change) */
int32_t *proto_committed_params(uint32_t *n);
uint8_t *proto_kv(uint32_t **n);
uint32_t entry_size(const uint8_t *p, uint32_t left);   /* a kv entry's bytes, 0: malformed */
void on_param_set(const frame_t *f);     /* params.c */

#endif
