/* sha256.h: FIPS 180-4 section 6.2, one 64-byte block at a time. */
#include "sha256.h"

static const uint32_t K[64] = {
    0x428a2f98u, 0x71374491u, 0xb5c0fbcfu, 0xe9b5dba5u, 0x3956c25bu, 0x59f111f1u, 0x923f82a4u,
    0xab1c5ed5u, 0xd807aa98u, 0x12835b01u, 0x243185beu, 0x550c7dc3u, 0x72be5d74u, 0x80deb1feu,
    0x9bdc06a7u, 0xc19bf174u, 0xe49b69c1u, 0xefbe4786u, 0x0fc19dc6u, 0x240ca1ccu, 0x2de92c6fu,
    0x4a7484aau, 0x5cb0a9dcu, 0x76f988dau, 0x983e5152u, 0xa831c66du, 0xb00327c8u, 0xbf597fc7u,
    0xc6e00bf3u, 0xd5a79147u, 0x06ca6351u, 0x14292967u, 0x27b70a85u, 0x2e1b2138u, 0x4d2c6dfcu,
    0x53380d13u, 0x650a7354u, 0x766a0abbu, 0x81c2c92eu, 0x92722c85u, 0xa2bfe8a1u, 0xa81a664bu,
    0xc24b8b70u, 0xc76c51a3u, 0xd192e819u, 0xd6990624u, 0xf40e3585u, 0x106aa070u, 0x19a4c116u,
    0x1e376c08u, 0x2748774cu, 0x34b0bcb5u, 0x391c0cb3u, 0x4ed8aa4au, 0x5b9cca4fu, 0x682e6ff3u,
    0x748f82eeu, 0x78a5636fu, 0x84c87814u, 0x8cc70208u, 0x90befffau, 0xa4506cebu, 0xbef9a3f7u,
    0xc67178f2u,
};

static uint32_t ror(uint32_t x, int n) { return (x >> n) | (x << (32 - n)); }

static void block(sha256_t *c)
{
    uint32_t w[64], a, b, d, e, f, g, h, k, t1, t2, cc;
    for (k = 0; k < 16; k++)
        w[k] = (uint32_t)c->block[4 * k] << 24 | (uint32_t)c->block[4 * k + 1] << 16
               | (uint32_t)c->block[4 * k + 2] << 8 | c->block[4 * k + 3];
    for (k = 16; k < 64; k++)      /* (6.6), (6.7): sigma0, sigma1 */
        w[k] = (ror(w[k - 2], 17) ^ ror(w[k - 2], 19) ^ (w[k - 2] >> 10)) + w[k - 7]
               + (ror(w[k - 15], 7) ^ ror(w[k - 15], 18) ^ (w[k - 15] >> 3)) + w[k - 16];
    a = c->h[0]; b = c->h[1]; cc = c->h[2]; d = c->h[3];
    e = c->h[4]; f = c->h[5]; g = c->h[6]; h = c->h[7];
    for (k = 0; k < 64; k++) {     /* (6.4), (6.5): Sigma1, Ch, Sigma0, Maj */
        t1 = h + (ror(e, 6) ^ ror(e, 11) ^ ror(e, 25)) + ((e & f) ^ (~e & g)) + K[k] + w[k];
        t2 = (ror(a, 2) ^ ror(a, 13) ^ ror(a, 22)) + ((a & b) ^ (a & cc) ^ (b & cc));
        h = g; g = f; f = e; e = d + t1;
        d = cc; cc = b; b = a; a = t1 + t2;
    }
    c->h[0] += a; c->h[1] += b; c->h[2] += cc; c->h[3] += d;
    c->h[4] += e; c->h[5] += f; c->h[6] += g; c->h[7] += h;
}

void sha256_init(sha256_t *c)
{
    static const uint32_t h0[8] = {0x6a09e667u, 0xbb67ae85u, 0x3c6ef372u, 0xa54ff53au,
                                   0x510e527fu, 0x9b05688cu, 0x1f83d9abu, 0x5be0cd19u};
    for (int k = 0; k < 8; k++)
        c->h[k] = h0[k];
    c->n = 0;
    c->total = 0;
}

void sha256_add(sha256_t *c, const uint8_t *p, uint32_t n)
{
    c->total += n;
    while (n--) {
        c->block[c->n++] = *p++;
        if (c->n == 64) {
            block(c);
            c->n = 0;
        }
    }
}

void sha256_done(sha256_t *c, uint8_t out[32])
{
    uint64_t bits = c->total * 8;
    uint8_t one = 0x80, zero = 0, len[8];
    int k;
    sha256_add(c, &one, 1);
    while (c->n != 56)
        sha256_add(c, &zero, 1);
    for (k = 0; k < 8; k++)
        len[k] = (uint8_t)(bits >> (56 - 8 * k));
    sha256_add(c, len, 8);
    for (k = 0; k < 32; k++)
        out[k] = (uint8_t)(c->h[k >> 2] >> (24 - 8 * (k & 3)));
}

void hmac_init(hmac_t *m, const uint8_t *key, uint32_t keylen)
{
    uint8_t ipad[64];
    uint32_t k;
    for (k = 0; k < 64; k++) {
        uint8_t b = k < keylen ? key[k] : 0;
        ipad[k] = b ^ 0x36u;
        m->opad[k] = b ^ 0x5Cu;
    }
    sha256_init(&m->inner);
    sha256_add(&m->inner, ipad, 64);
}

void hmac_add(hmac_t *m, const uint8_t *p, uint32_t n)
{
    sha256_add(&m->inner, p, n);
}

void hmac_done(hmac_t *m, uint8_t out[32])
{
    sha256_t outer;
    uint8_t ih[32];
    sha256_done(&m->inner, ih);
    sha256_init(&outer);
    sha256_add(&outer, m->opad, 64);
    sha256_add(&outer, ih, 32);
    sha256_done(&outer, out);
}
