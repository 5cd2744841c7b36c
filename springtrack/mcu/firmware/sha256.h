/* SHA-256 (FIPS 180-4) and HMAC-SHA256 (RFC 2104), for the host link's signed frames
 * (docs/protocol.md, "Security of the control path"; springtrack/wire.py make_tag). */
#ifndef SPRINGTRACK_FW_SHA256_H
#define SPRINGTRACK_FW_SHA256_H

#include <stdint.h>

typedef struct {
    uint32_t h[8];
    uint8_t block[64];
    uint32_t n;              /* bytes in block */
    uint64_t total;          /* bytes hashed */
} sha256_t;

void sha256_init(sha256_t *c);
void sha256_add(sha256_t *c, const uint8_t *p, uint32_t n);
void sha256_done(sha256_t *c, uint8_t out[32]);

/* HMAC with a key of at most 64 bytes: start, add the message in parts, finish */
typedef struct {
    sha256_t inner;
    uint8_t opad[64];
} hmac_t;

void hmac_init(hmac_t *m, const uint8_t *key, uint32_t keylen);
void hmac_add(hmac_t *m, const uint8_t *p, uint32_t n);
void hmac_done(hmac_t *m, uint8_t out[32]);

#endif
