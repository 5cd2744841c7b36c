/* Byte and text builders for payloads, reasons and INFO's JSON (no libc): a buffer with a
 * capacity, appended to; what does not fit is cut and `over` set. */
#ifndef SPRINGTRACK_FW_TEXT_H
#define SPRINGTRACK_FW_TEXT_H

#include <stdint.h>

typedef struct {
    uint8_t *p;
    uint32_t n, cap;
    uint8_t over;
} buf_t;

static inline void b_u8(buf_t *b, uint32_t v)
{
    if (b->n < b->cap)
        b->p[b->n++] = (uint8_t)v;
    else
        b->over = 1;
}
static inline void b_u16(buf_t *b, uint32_t v) { b_u8(b, v); b_u8(b, v >> 8); }
static inline void b_u32(buf_t *b, uint32_t v) { b_u16(b, v); b_u16(b, v >> 16); }
static inline void b_u64(buf_t *b, uint64_t v) { b_u32(b, (uint32_t)v); b_u32(b, (uint32_t)(v >> 32)); }
static inline void b_bytes(buf_t *b, const uint8_t *s, uint32_t n)
{
    while (n--)
        b_u8(b, *s++);
}
__attribute__((noinline, unused)) static void b_str(buf_t *b, const char *s)
{
    while (*s)
        b_u8(b, (uint8_t)*s++);
}
/* a signed decimal */
__attribute__((noinline, unused)) static void b_int(buf_t *b, int64_t v)
{
    char d[21];
    int k = 0;
    uint64_t u = v < 0 ? (uint64_t)0 - (uint64_t)v : (uint64_t)v;
    if (v < 0)
        b_u8(b, '-');
    do {
        uint64_t q = 0, r = u;           /* u / 10 by shifts: no 64-bit division helper */
        for (int bit = 63; bit >= 0; bit--) {
            if ((r >> bit) >= 10u) {
                r -= (uint64_t)10u << bit;
                q |= (uint64_t)1 << bit;
            }
        }
        d[k++] = (char)('0' + (int)r);
        u = q;
    } while (u);
    while (k)
        b_u8(b, (uint8_t)d[--k]);
}
/* a JSON string (quotes, backslash and control characters escaped; UTF-8 kept) */
__attribute__((noinline, unused)) static void b_json_str(buf_t *b, const uint8_t *s, uint32_t n)
{
    static const char hex[] = "0123456789abcdef";
    b_u8(b, '"');
    while (n--) {
        uint8_t c = *s++;
        if (c == '"' || c == '\\') {
            b_u8(b, '\\');
            b_u8(b, c);
        } else if (c < 0x20) {
            b_str(b, "\\u00");
            b_u8(b, (uint8_t)hex[c >> 4]);
            b_u8(b, (uint8_t)hex[c & 15]);
        } else {
            b_u8(b, c);
        }
    }
    b_u8(b, '"');
}

#endif
