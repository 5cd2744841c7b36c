/* The host link's framing (link.h): the firmware end of springtrack/wire.py's
 * FrameReader, encode_frame and cobs_encode / cobs_decode. */
#include "link.h"
#include "board.h"

link_counts_t link_counts;

/* a frame's stuffed bytes up to its 0x00, then its body: COBS decodes in place */
static uint8_t rx[WIRE_MAX_ENCODED + 1];
static uint32_t rx_n;
static uint8_t rx_skipping;                  /* dropping bytes up to the next delimiter */
#define body rx

/* CRC-32, reflected polynomial 0xEDB88320, four bits at a time (64 bytes of table) */
static const uint32_t crc_nibble[16] = {
    0x00000000u, 0x1DB71064u, 0x3B6E20C8u, 0x26D930ACu, 0x76DC4190u, 0x6B6B51F4u,
    0x4DB26158u, 0x5005713Cu, 0xEDB88320u, 0xF00F9344u, 0xD6D6A3E8u, 0xCB61B38Cu,
    0x9B64C2B0u, 0x86D3D2D4u, 0xA00AE278u, 0xBDBDF21Cu,
};

uint32_t crc32(uint32_t crc, const uint8_t *p, uint32_t n)
{
    crc = ~crc;
    while (n--) {
        crc ^= *p++;
        crc = (crc >> 4) ^ crc_nibble[crc & 15u];
        crc = (crc >> 4) ^ crc_nibble[crc & 15u];
    }
    return ~crc;
}

void link_init(void)
{
    uart_init();
    rx_n = 0;
    rx_skipping = 0;
    uart_putc(0);                            /* ends whatever partial frame the host holds */
}

/* COBS decode of rx[0..n) into body (= rx: the output never overtakes the input); -1 on a
   zero byte inside or a short block */
static int32_t cobs_decode(uint32_t n)
{
    uint32_t i = 0, k = 0;
    while (i < n) {
        uint32_t code = rx[i], end = i + code, j;
        if (end > n)
            return -1;
        for (j = i + 1; j < end; j++)
            body[k++] = rx[j];
        i = end;
        if (code < 255 && i < n)
            body[k++] = 0;
    }
    return (int32_t)k;
}

static uint32_t le16(const uint8_t *p) { return (uint32_t)p[0] | (uint32_t)p[1] << 8; }
static uint32_t le32(const uint8_t *p) { return le16(p) | le16(p + 2) << 16; }

static void frame_done(void)
{
    int32_t n = cobs_decode(rx_n);
    frame_t f;
    if (n < 0) {
        link_counts.cobs_errors++;
        return;
    }
    if (n < WIRE_HEADER + WIRE_CRC) {
        link_counts.malformed++;
        return;
    }
    if (crc32(0, body, (uint32_t)n - WIRE_CRC) != le32(body + n - WIRE_CRC)) {
        link_counts.crc_errors++;
        return;
    }
    f.version = body[0];
    f.type = body[1];
    f.flags = body[2];
    f.seq = (uint16_t)le16(body + 3);
    f.header = body;
    f.payload = body + WIRE_HEADER;
    f.len = (uint32_t)n - WIRE_HEADER - WIRE_CRC;
    f.sig = 0;
    if (f.flags & WIRE_FLAG_SIGNED) {
        if (f.len < WIRE_SIG_LEN) {
            link_counts.malformed++;
            return;
        }
        f.len -= WIRE_SIG_LEN;
        f.sig = f.payload + f.len;
    }
    if (f.len > WIRE_MAX_PAYLOAD) {
        link_counts.malformed++;
        return;
    }
    link_counts.frames++;
    proto_frame(&f);
}

void link_poll(void)
{
    int c;
    while ((c = uart_getc()) >= 0) {
        link_counts.bytes++;
        if (c == 0) {
            if (rx_skipping)
                rx_skipping = 0;
            else if (rx_n)
                frame_done();
            rx_n = 0;
            continue;
        }
        if (rx_skipping)
            continue;
        if (rx_n >= WIRE_MAX_ENCODED) {       /* no delimiter in sight: drop, resync later */
            link_counts.oversize++;
            rx_n = 0;
            rx_skipping = 1;
            continue;
        }
        rx[rx_n++] = (uint8_t)c;
    }
}

static void put(uint8_t c)
{
    uart_putc(c);
    link_counts.tx_bytes++;
}

/* the body being sent: header, payload, CRC, without copying the payload */
static struct {
    uint8_t head[WIRE_HEADER], crc[WIRE_CRC];
    const uint8_t *payload;
    uint32_t len;
} txb;

static uint8_t tx_at(uint32_t i)
{
    if (i < WIRE_HEADER)
        return txb.head[i];
    i -= WIRE_HEADER;
    return i < txb.len ? txb.payload[i] : txb.crc[i - txb.len];
}

/* wire.cobs_encode of the body's n bytes: blocks between zeros, at most 254 bytes after a
   code byte */
static void cobs_send(uint32_t n)
{
    uint32_t i = 0, j, blen;
    for (;;) {
        j = i;
        while (j < n && tx_at(j) != 0)
            j++;
        blen = j - i;
        while (blen >= 254) {
            put(255);
            for (uint32_t e = i + 254; i < e; i++)
                put(tx_at(i));
            blen -= 254;
        }
        put((uint8_t)(blen + 1));
        for (; i < j; i++)
            put(tx_at(i));
        if (j >= n)
            break;
        i = j + 1;
    }
}

void link_send(uint8_t version, uint8_t type, uint16_t seq, const uint8_t *payload, uint32_t len)
{
    uint32_t crc;
    if (len > WIRE_MAX_PAYLOAD)
        return;
    txb.head[0] = version;
    txb.head[1] = type;
    txb.head[2] = 0;
    txb.head[3] = (uint8_t)seq;
    txb.head[4] = (uint8_t)(seq >> 8);
    txb.payload = payload;
    txb.len = len;
    crc = crc32(crc32(0, txb.head, WIRE_HEADER), payload, len);
    txb.crc[0] = (uint8_t)crc;
    txb.crc[1] = (uint8_t)(crc >> 8);
    txb.crc[2] = (uint8_t)(crc >> 16);
    txb.crc[3] = (uint8_t)(crc >> 24);
    put(0);
    cobs_send(WIRE_HEADER + len + WIRE_CRC);
    put(0);
    link_counts.tx_frames++;
}
