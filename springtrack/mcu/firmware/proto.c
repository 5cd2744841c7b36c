/* The host link's state machine: the firmware end of docs/protocol.md, as
 * firmware_sim/link.py serves it on a serial line (one session), for a firmware that
 * takes models and parameters as words images (springtrack/wire.py encode_image; INFO says
 * model_format "words"): HELLO/INFO, model upload (MODEL_BEGIN / CHUNK / COMMIT, checked
 * by check.c), PARAM_GET (the parameters the last image carried), START / STOP / RESET,
 * STATS, SHUTDOWN, HEARTBEAT (pings answered, its own once a second), TELEMETRY,
 * ENERGIES, APPLIED and NOTICE.  Replies to the last
 * 16 ACKed commands are kept, so that a retry is answered again and not executed twice.
 * Refused (docs/mcu.md): PARAM_SET by name (hostctl sends a parameters image instead),
 * ACQUIRE (no acquisition search), MODEL_GET (no TOML kept).  With a key
 * built in (link_key.h, springtrack mcu build --key-file), every frame but HELLO must be
 * signed as wire.Signer signs it; others are dropped without an answer and counted. */
#include "board.h"
#include "check.h"
#include "engine.h"
#include "fixed_step.h"
#include "link.h"
#include "link_key.h"
#include "proto.h"
#include "sha256.h"
#include "text.h"

#define MODEL_WORDS (FX_MODEL_HEAD + FX_MODEL_TRACKER * FX_MAX_TRACKERS \
                     + FX_MODEL_CONNECTION * FX_MAX_CONNECTIONS)
#define KV_MAX (WIRE_MAX_PAYLOAD - 8)    /* one PARAM_VALUE part (wire.split_kv's budget) */
#define NAME_MAX WIRE_INFO_NAME_BUDGET
#define IDS_MAX 1024
#define IMAGE_MAX (WIRE_IMAGE_HDR + KV_MAX + 2 + NAME_MAX + 1 + IDS_MAX + 8 \
                   + 4 * MODEL_WORDS + 4 * FX_PARAMS_WORDS)
#define CACHE 16

uint32_t fw_stack_used(void);           /* startup.c */
#define FIRMWARE "springtrack-mcu 0.1 (" BOARD_NAME ", fixed-point kernel)"

proto_session_t sess;

/* the committed configuration: name, tracker ids (str8 each), parameters (kv list) */
static uint8_t name[NAME_MAX], ids[IDS_MAX], kv[KV_MAX];
static uint32_t name_n, ids_n, ids_count, kv_n, trackers, connections, have_ids;

/* the upload: the image, and which of its bytes arrived */
static uint8_t image[IMAGE_MAX] __attribute__((aligned(4)));
static uint8_t have[(IMAGE_MAX + 7) / 8];
static uint32_t up_total, up_crc, up_active, image_is_model;
/* the committed words in the upload buffer (aligned by words_at), until an upload begins */
static int32_t *c_model, *c_params;
static uint32_t c_model_n, c_params_n;

static struct {
    uint16_t seq;
    uint8_t type, used;
    uint32_t crc, value;
} cache[CACHE];
static uint32_t cache_next;

static uint8_t out_[WIRE_MAX_PAYLOAD];

void proto_send(uint8_t type, const uint8_t *p, uint32_t n)
{
    link_send(WIRE_VERSION, type, sess.tx_seq++, p, n);
}

buf_t proto_out(void)
{
    buf_t b = {out_, 0, sizeof out_, 0};
    return b;
}

void proto_ack(const frame_t *f, uint32_t value)
{
    buf_t b = proto_out();
    b_u16(&b, f->seq);
    b_u8(&b, f->type);
    b_u32(&b, value);
    sess.acks++;
    proto_send(MSG_ACK, b.p, b.n);
    cache[cache_next].seq = f->seq;
    cache[cache_next].type = f->type;
    cache[cache_next].crc = crc32(0, f->payload, f->len);
    cache[cache_next].value = value;
    cache[cache_next].used = 1;
    cache_next = (cache_next + 1) % CACHE;
}

/* a NACK whose reason is `why` (already built in its own buffer) */
void proto_nack(const frame_t *f, uint8_t version, uint8_t code, const buf_t *why)
{
    buf_t b = proto_out();
    uint32_t n = why->n > WIRE_MAX_PAYLOAD - 8 ? WIRE_MAX_PAYLOAD - 8 : why->n;
    b_u16(&b, f->seq);
    b_u8(&b, f->type);
    b_u8(&b, code);
    b_u16(&b, n);
    b_bytes(&b, why->p, n);
    sess.nacks++;
    link_send(version, MSG_NACK, sess.tx_seq++, b.p, b.n);
}

static uint8_t why_[320];               /* a NACK's reason */
buf_t proto_why(void)
{
    buf_t b = {why_, 0, sizeof why_, 0};
    return b;
}

void proto_nack_text(const frame_t *f, uint8_t code, const char *text)
{
    buf_t w = proto_why();
    b_str(&w, text);
    proto_nack(f, WIRE_VERSION, code, &w);
}

void proto_nack_kernel_refused(const frame_t *f, const char *what, int32_t rc)
{
    buf_t w = proto_why();
    b_str(&w, what);
    b_str(&w, " (fx status ");
    b_int(&w, rc);
    b_u8(&w, ')');
    sess.updates_rejected++;
    proto_nack(f, WIRE_VERSION, NACK_INTERNAL, &w);
}

static uint32_t le16(const uint8_t *p) { return (uint32_t)p[0] | (uint32_t)p[1] << 8; }
static uint32_t le32(const uint8_t *p) { return le16(p) | le16(p + 2) << 16; }

static void version_nack(const frame_t *f, uint32_t host)
{
    buf_t w = proto_why();
    b_str(&w, "firmware=v");
    b_int(&w, WIRE_VERSION);
    b_str(&w, " host=v");
    b_int(&w, host);
    b_str(&w, ": protocol version mismatch (firmware speaks v");
    b_int(&w, WIRE_VERSION);
    b_str(&w, ", host sent v");
    b_int(&w, host);
    b_u8(&w, ')');
    sess.version_refused++;
    proto_nack(f, WIRE_VERSION, NACK_VERSION_MISMATCH, &w);
}

/* ---- INFO ---------------------------------------------------------------------------- */
static void json_key(buf_t *b, const char *k)
{
    b_u8(b, b->n > 0 && b->p[b->n - 1] != '{' ? ',' : ' ');
    if (b->p[b->n - 1] == ' ')
        b->n--;
    b_u8(b, '"');
    b_str(b, k);
    b_str(b, "\":");
}

static void json_int(buf_t *b, const char *k, int64_t v)
{
    json_key(b, k);
    b_int(b, v);
}

static void json_text(buf_t *b, const char *k, const char *v)
{
    json_key(b, k);
    b_u8(b, '"');
    b_str(b, v);
    b_u8(b, '"');
}

static const char *state_name(void)
{
    static const char *const names[] = {"idle", "running", "stopped", "ended"};
    return names[eng.state];
}

/* INFO's JSON: with the tracker ids while they fit, then without (trackers_omitted), then
   with the model name cut to 128 bytes (wire.encode_info's order) */
static void info_json(buf_t *b, int level)
{
    uint32_t k, pos;
    b_u8(b, '{');
    json_text(b, "backend", "fixed");
    json_text(b, "board", BOARD_NAME);
    json_int(b, "connections", connections);
    json_text(b, "firmware", FIRMWARE);
    json_int(b, "generation", eng.generation);
    json_int(b, "height", eng.height);
    json_int(b, "max_connections", FX_MAX_CONNECTIONS);
    json_int(b, "max_trackers", FX_MAX_TRACKERS);
    json_key(b, "model");
    if (eng.loaded) {
        uint32_t n = name_n;
        if (level >= 2 && n > 128) {     /* cut at a UTF-8 character boundary */
            n = 128;
            while (n && (name[n] & 0xC0) == 0x80)
                n--;
        }
        b_json_str(b, name, n);
    } else {
        b_str(b, "null");
    }
    json_text(b, "model_format", WIRE_MODEL_FORMAT_WORDS);
    json_text(b, "role", sess.role == ROLE_MONITOR ? "monitor" : "operator");
    json_key(b, "running");
    b_str(b, eng.state == ST_RUNNING ? "true" : "false");
    json_int(b, "sessions", sess.session ? 1 : 0);
    json_text(b, "state", state_name());
    json_int(b, "telemetry_period_us", ENGINE_PERIOD_US);
    if (eng.loaded && have_ids && level == 0) {
        json_key(b, "trackers");
        b_u8(b, '[');
        for (k = 0, pos = 0; k < ids_count; k++) {
            if (k)
                b_u8(b, ',');
            b_json_str(b, ids + pos + 1, ids[pos]);
            pos += 1u + ids[pos];
        }
        b_u8(b, ']');
    } else if (eng.loaded) {
        json_int(b, "trackers_omitted", trackers);
    }
    if (level >= 2)
        b_str(b, ",\"truncated\":[\"model\"]");
    json_int(b, "width", eng.width);
    b_u8(b, '}');
}

static void send_info(void)
{
    buf_t b;
    int level;
    uint32_t k;
    for (level = 0; level < 3; level++) {
        b = proto_out();
        b_u16(&b, WIRE_VERSION);
        for (k = 0; k < WIRE_NONCE_LEN; k++)
            b_u8(&b, sess.nonce[k]);
        b_u8(&b, (eng.state == ST_RUNNING ? 2u : 0u) | (LINK_KEY_LEN ? 1u : 0u));
        b_u32(&b, eng.generation);
        b_u16(&b, 0);                    /* the JSON's length, filled in below */
        info_json(&b, level);
        if (!b.over)
            break;
    }
    b.p[2 + WIRE_NONCE_LEN + 5] = (uint8_t)(b.n - (2 + WIRE_NONCE_LEN + 7));
    b.p[2 + WIRE_NONCE_LEN + 6] = (uint8_t)((b.n - (2 + WIRE_NONCE_LEN + 7)) >> 8);
    proto_send(MSG_INFO, b.p, b.n);
}

/* the session nonce: SHA-256 of the key, the SysTick count, the session number and the
   previous nonce (no hardware random source is used: see docs/mcu.md) */
static void new_nonce(void)
{
    sha256_t c;
    uint8_t h[32];
    uint32_t t = board_ticks(), k;
    sha256_init(&c);
    sha256_add(&c, link_key, LINK_KEY_LEN);
    sha256_add(&c, (const uint8_t *)&t, 4);
    sha256_add(&c, (const uint8_t *)&sess.sessions, 4);
    sha256_add(&c, sess.nonce, WIRE_NONCE_LEN);
    sha256_done(&c, h);
    for (k = 0; k < WIRE_NONCE_LEN; k++)
        sess.nonce[k] = h[k];
    sess.sessions++;
}

/* wire.ReplayGuard.check: 0 if the frame is signed, its tag verifies and its counter is
   above every counter accepted in this session; else which check failed (counted) */
static int signature_ok(const frame_t *f)
{
    hmac_t m;
    uint8_t tag[32], diff = 0;
    uint64_t counter = 0;
    uint32_t k;
    if (!f->sig) {
        sess.auth_unsigned++;
        return 0;
    }
    for (k = 0; k < 8; k++)
        counter |= (uint64_t)f->sig[k] << (8 * k);
    hmac_init(&m, link_key, LINK_KEY_LEN);
    hmac_add(&m, sess.nonce, WIRE_NONCE_LEN);
    hmac_add(&m, f->header, WIRE_HEADER);
    hmac_add(&m, f->payload, f->len);
    hmac_add(&m, f->sig, 8);
    hmac_done(&m, tag);
    for (k = 0; k < WIRE_TAG_LEN; k++)   /* constant time */
        diff |= (uint8_t)(tag[k] ^ f->sig[8 + k]);
    if (diff) {
        sess.auth_bad_tag++;
        return 0;
    }
    if (counter <= sess.last_counter) {
        sess.auth_replay++;
        return 0;
    }
    sess.last_counter = counter;
    return 1;
}

static void on_hello(const frame_t *f)
{
    uint32_t version, nl;
    if (f->len < 3 || f->len < 3 + f->payload[2]) {
        proto_nack_text(f, NACK_MALFORMED, "HELLO: truncated");
        return;
    }
    version = le16(f->payload);
    nl = f->payload[2];
    if (version != WIRE_VERSION) {
        version_nack(f, version);
        return;
    }
    if (f->len > 3 + nl + 1 || (f->len == 4 + nl && f->payload[3 + nl] > ROLE_MONITOR)) {
        proto_nack_text(f, NACK_MALFORMED, "HELLO: unknown role or trailing bytes");
        return;
    }
    if (sess.session && f->seq == sess.hello_seq && crc32(0, f->payload, f->len) == sess.hello_crc) {
        send_info();                     /* a retried HELLO: the same session, same nonce */
        return;
    }
    sess.hello_seq = f->seq;
    sess.hello_crc = crc32(0, f->payload, f->len);
    sess.role = f->len == 4 + nl ? f->payload[3 + nl] : ROLE_OPERATOR;
    sess.session = 1;
    sess.rx_last = f->seq;
    new_nonce();
    sess.authenticated = 0;                /* a keyed session starts with its first authentic */
    sess.last_counter = 0;                 /* frame */
    send_info();
}

/* ---- key/value replies (STATS, PARAM_VALUE) in parts ----------------------------------- */
#define ENTRIES 1536
#define MAX_ENTRIES 96
static uint8_t entries_[ENTRIES];
static uint32_t ends[MAX_ENTRIES], nentries;
static buf_t ent;

static void entries_begin(void)
{
    ent.p = entries_;
    ent.n = 0;
    ent.cap = ENTRIES;
    ent.over = 0;
    nentries = 0;
}

static void entry_end(void)
{
    if (nentries < MAX_ENTRIES && !ent.over)
        ends[nentries++] = ent.n;
    else if (nentries)
        ent.n = ends[nentries - 1];       /* no room: the entry is left out */
}

/* an entry: str8 name, then 'i' int64 or 's' str8 */
static void kv_int(const char *k, int64_t v)
{
    uint32_t n = 0;
    while (k[n])
        n++;
    b_u8(&ent, n);
    b_str(&ent, k);
    b_u8(&ent, 'i');
    b_u64(&ent, (uint64_t)v);
    entry_end();
}

static void kv_text(const char *k, const char *v)
{
    uint32_t n = 0, m = 0;
    while (k[n])
        n++;
    while (v[m])
        m++;
    b_u8(&ent, n);
    b_str(&ent, k);
    b_u8(&ent, 's');
    b_u8(&ent, m);
    b_str(&ent, v);
    entry_end();
}

/* the entries in parts as wire.split_kv splits a dict: at most 255 entries and KV_MAX
   bytes (its count byte included) per part; replies u16 seq, u8 part, u8 parts, kv list */
static uint32_t split(uint32_t i)
{
    uint32_t j = i, from = i ? ends[i - 1] : 0;
    while (j < nentries && j - i < 255 && (j == i || 1 + ends[j] - from <= KV_MAX))
        j++;
    return j;
}

static void send_parts(const frame_t *f, uint8_t type)
{
    uint32_t parts = 0, part = 0, i = 0, j;
    do {
        parts++;
        i = split(i);
    } while (i < nentries);
    i = 0;
    do {
        buf_t b = proto_out();
        uint32_t from = i ? ends[i - 1] : 0;
        j = split(i);
        b_u16(&b, f->seq);
        b_u8(&b, part++);
        b_u8(&b, parts);
        b_u8(&b, j - i);
        b_bytes(&b, entries_ + from, (j > i ? ends[j - 1] : from) - from);
        proto_send(type, b.p, b.n);
        i = j;
    } while (i < nentries);
}

static void on_stats(const frame_t *f)
{
    static const char *const kernel[] = {
        "kernel.events_valid", "kernel.events_assigned", "kernel.skipped_back_in_time",
        "kernel.skipped_outside_sensor", "kernel.spring_updates", "kernel.index_updates",
        "kernel.saturated_position", "kernel.saturated_activity", "kernel.saturated_energy",
        "kernel.saturated_inverse", "kernel.last_t"};
    extern int64_t mcu_counters[];
    uint32_t k;
    if (f->len) {
        proto_nack_text(f, NACK_MALFORMED, "STATS: a request has an empty payload");
        return;
    }
    entries_begin();
    kv_text("state", state_name());
    kv_text("firmware", FIRMWARE);
    kv_int("generation", eng.generation);
    kv_int("events_decoded", (int64_t)eng.events_decoded);
    kv_int("events_tracked", (int64_t)eng.events_tracked);
    kv_int("snapshots", (int64_t)eng.snapshots);
    kv_int("telemetry_sent", sess.telemetry);
    kv_int("replays", (int64_t)eng.replays);
    kv_int("decode.words", (int64_t)eng.words);
    kv_int("decode.stream_words", eng.word_bytes ? eng.nbytes / eng.word_bytes : 0);
    kv_int("decode.gap_skipped", (int64_t)eng.gap_skipped);
    kv_int("decode.outside_sensor", (int64_t)eng.outside_sensor);
    kv_int("decode.time_high", (int64_t)eng.time_high);
    kv_int("decode.time_wraps", (int64_t)eng.time_wraps);
    kv_int("decode.time_backwards", (int64_t)eng.time_backwards);
    kv_int("decode.triggers", (int64_t)eng.triggers);
    kv_int("decode.others", (int64_t)eng.others);
    kv_int("decode.unknown_type", (int64_t)eng.unknown_type);
    kv_int("decode.width", eng.width);
    kv_int("decode.height", eng.height);
    if (eng.loaded)
        for (k = 0; k < sizeof kernel / sizeof kernel[0]; k++)
            kv_int(kernel[k], mcu_counters[k]);
    kv_int("updates_rejected", sess.updates_rejected);
    kv_int("param_ticks", sess.param_ticks);
    {                                    /* the kernel's parameter words now */
        uint32_t nw;
        const int32_t *pw = proto_committed_params(&nw);
        kv_int("params_crc32", pw ? crc32(0, (const uint8_t *)pw, 4 * nw) : 0);
    }
    kv_int("stack_used_bytes", fw_stack_used());
    kv_int("work_ticks", (int64_t)eng.work_ticks);
    kv_int("decode_ticks", (int64_t)eng.decode_ticks);
    kv_int("link.rx_frames", link_counts.frames);
    kv_int("link.rx_bytes", link_counts.bytes);
    kv_int("link.crc_errors", link_counts.crc_errors);
    kv_int("link.cobs_errors", link_counts.cobs_errors);
    kv_int("link.malformed", link_counts.malformed);
    kv_int("link.oversize", link_counts.oversize);
    kv_int("link.rx_lost", sess.rx_lost);
    kv_int("link.rx_retries", sess.retries);
    kv_int("link.tx_frames", link_counts.tx_frames);
    kv_int("link.tx_bytes", link_counts.tx_bytes);
    kv_int("link.acks", sess.acks);
    kv_int("link.nacks", sess.nacks);
    kv_int("link.forbidden", sess.forbidden);
    kv_int("link.version_refused", sess.version_refused);
    kv_int("link.auth_unsigned", sess.auth_unsigned);
    kv_int("link.auth_bad_tag", sess.auth_bad_tag);
    kv_int("link.auth_replay", sess.auth_replay);
    kv_text("session.role", !sess.session ? "" : sess.role == ROLE_MONITOR ? "monitor" : "operator");
    send_parts(f, MSG_STATS);
}

/* ---- PARAM_GET: the entries of the committed parameters' kv list ---------------------- */
/* the size of the kv entry at p (name, typed value), 0 if malformed */
uint32_t entry_size(const uint8_t *p, uint32_t left)
{
    uint32_t n;
    if (left < 2 || left < 2u + p[0])
        return 0;
    n = 1u + p[0];
    switch (p[n]) {
    case 'i': case 'f': n += 9; break;
    case 'b': n += 2; break;
    case 's': n += 2u + (n + 1 < left ? p[n + 1] : 255u); break;
    default: return 0;
    }
    return n <= left ? n : 0;
}

static int find_entry(const uint8_t *nm, uint32_t nl, uint32_t *at, uint32_t *size)
{
    uint32_t pos = 1, k, c;
    for (c = 0; kv_n && c < kv[0]; c++) {
        uint32_t s = entry_size(kv + pos, kv_n - pos);
        if (!s)
            return 0;
        if (kv[pos] == nl) {
            for (k = 0; k < nl && kv[pos + 1 + k] == nm[k]; k++)
                ;
            if (k == nl) {
                *at = pos;
                *size = s;
                return 1;
            }
        }
        pos += s;
    }
    return 0;
}

static void on_param_get(const frame_t *f)
{
    uint32_t count, pos = 1, c, at, size;
    entries_begin();
    if (f->len < 1) {
        proto_nack_text(f, NACK_MALFORMED, "PARAM_GET: truncated at count");
        return;
    }
    count = f->payload[0];
    for (c = 0; c < count; c++) {
        if (pos >= f->len || pos + 1 + f->payload[pos] > f->len) {
            proto_nack_text(f, NACK_MALFORMED, "PARAM_GET: truncated at a name");
            return;
        }
        if (!find_entry(f->payload + pos + 1, f->payload[pos], &at, &size)) {
            buf_t w = proto_why();
            b_str(&w, "unknown parameter(s) ");
            b_bytes(&w, f->payload + pos + 1, f->payload[pos]);
            b_str(&w, kv_n ? "" : " (no parameters yet: load a model)");
            proto_nack(f, WIRE_VERSION, NACK_UNKNOWN_NAME, &w);
            return;
        }
        b_bytes(&ent, kv + at, size);
        entry_end();
        pos += 1u + f->payload[pos];
    }
    if (pos != f->len) {
        proto_nack_text(f, NACK_MALFORMED, "PARAM_GET: unexpected trailing bytes");
        return;
    }
    if (count == 0 && kv_n) {            /* all of them */
        pos = 1;
        for (c = 0; c < kv[0]; c++) {
            size = entry_size(kv + pos, kv_n - pos);
            b_bytes(&ent, kv + pos, size);
            entry_end();
            pos += size;
        }
    }
    send_parts(f, MSG_PARAM_VALUE);
}

/* ---- the words image upload -------------------------------------------------------------- */
static void on_model_begin(const frame_t *f)
{
    uint32_t k;
    if (f->len != 8) {
        proto_nack_text(f, NACK_MALFORMED, "MODEL_BEGIN/COMMIT: payload is not 8 bytes");
        return;
    }
    if (le32(f->payload) == 0 || le32(f->payload) > IMAGE_MAX) {
        buf_t w = proto_why();
        b_str(&w, "model of ");
        b_int(&w, le32(f->payload));
        b_str(&w, " bytes: must be 1..");
        b_int(&w, IMAGE_MAX);
        b_str(&w, " (this firmware takes words images of its capacity)");
        proto_nack(f, WIRE_VERSION, NACK_OUT_OF_RANGE, &w);
        return;
    }
    up_total = le32(f->payload);
    up_crc = le32(f->payload + 4);
    up_active = 1;
    image_is_model = 0;                  /* the committed image is being overwritten */
    c_params = 0;
    for (k = 0; k < (up_total + 7) / 8; k++)
        have[k] = 0;
    proto_ack(f, 0);
}

static void on_model_chunk(const frame_t *f)
{
    uint32_t off, n, k;
    if (f->len < 4) {
        proto_nack_text(f, NACK_MALFORMED, "MODEL_CHUNK: payload shorter than its 4-byte offset");
        return;
    }
    if (!up_active) {
        proto_nack_text(f, NACK_BAD_STATE, "MODEL_CHUNK without MODEL_BEGIN");
        return;
    }
    off = le32(f->payload);
    n = f->len - 4;
    if (off > up_total || n > up_total - off) {
        proto_nack_text(f, NACK_OUT_OF_RANGE, "chunk beyond the announced length");
        return;
    }
    for (k = 0; k < n; k++) {
        image[off + k] = f->payload[4 + k];
        have[(off + k) >> 3] |= (uint8_t)(1u << ((off + k) & 7));
    }
    proto_ack(f, 0);
}

/* image fields (springtrack.mcu.words.decode_image); 0 on a truncated image */
typedef struct {
    uint32_t kind, kv_at, kv_n, name_at, name_n, ids_at, ids_n, ids_count;
    uint32_t model_at, model_n, params_at, params_n;
} image_t;

static int parse_image(image_t *m, uint32_t total)
{
    uint32_t pos = WIRE_IMAGE_HDR, k;
    if (total < WIRE_IMAGE_HDR || le32(image) != WIRE_IMAGE_MAGIC
        || image[4] != WIRE_IMAGE_VERSION || (image[5] != IMAGE_MODEL && image[5] != IMAGE_PARAMS))
        return 0;
    m->kind = image[5];
    m->kv_at = pos;
    m->kv_n = le16(image + 6);
    pos += m->kv_n;
    if (m->kind == IMAGE_MODEL) {
        if (pos + 2 > total)
            return 0;
        m->name_n = le16(image + pos);
        m->name_at = pos + 2;
        pos += 2 + m->name_n;
        if (pos + 1 > total)
            return 0;
        m->ids_count = image[pos++];
        m->ids_at = pos;
        for (k = 0; k < m->ids_count; k++) {
            if (pos + 1 > total)
                return 0;
            pos += 1u + image[pos];
        }
        m->ids_n = pos - m->ids_at;
        if (pos + 4 > total)
            return 0;
        m->model_n = le32(image + pos);
        m->model_at = pos + 4;
        if (m->model_n > MODEL_WORDS || m->model_at + 4 * m->model_n > total)
            return 0;
        pos = m->model_at + 4 * m->model_n;
    }
    if (pos + 4 > total)
        return 0;
    m->params_n = le32(image + pos);
    m->params_at = pos + 4;
    if (m->params_n > FX_PARAMS_WORDS || m->params_at + 4 * m->params_n != total)
        return 0;
    return 1;
}

/* the kv list is well-formed (so PARAM_GET can walk it) */
static int kv_ok(const uint8_t *p, uint32_t n)
{
    uint32_t pos = 1, c, s;
    if (n == 0 || n > KV_MAX)
        return 0;
    for (c = 0; c < p[0]; c++) {
        s = entry_size(p + pos, n - pos);
        if (!s)
            return 0;
        pos += s;
    }
    return pos == n;
}

/* the model name: no control characters, within INFO's budget */
static int name_check(const uint8_t *p, uint32_t n, buf_t *w)
{
    uint32_t k;
    if (n == 0) {
        b_str(w, "name must be a non-empty string");
        return NACK_INVALID_MODEL;
    }
    if (n > NAME_MAX) {
        b_str(w, "name takes more than ");
        b_int(w, NAME_MAX);
        b_str(w, " bytes in INFO (springtrack.wire.INFO_NAME_BUDGET)");
        return NACK_TOO_LONG;
    }
    for (k = 0; k < n; k++)
        if (p[k] < 0x20 || p[k] == 0x7F) {
            b_str(w, "name contains a control character");
            return NACK_INVALID_MODEL;
        }
    return 0;
}

/* the image's words, as int32 (the image is 4-byte aligned, the words maybe not) */
static int32_t *words_at(uint32_t at, uint32_t n)
{
    uint32_t k;
    int32_t *w = (int32_t *)(void *)(image + (at & ~3u));
    if (at & 3u)                         /* move them down to an aligned address */
        for (k = 0; k < 4 * n; k++)
            image[(at & ~3u) + k] = image[at + k];
    return w;
}

static void commit(const frame_t *f)
{
    image_t m;
    buf_t w = proto_why();
    int code = 0, rc;
    uint32_t k;
    int32_t *model = 0, *params;
    if (!parse_image(&m, up_total)) {
        proto_nack_text(f, NACK_INVALID_MODEL, "not a words image of this firmware's version and "
                  "capacity (springtrack.mcu.words.encode_image; hostctl sends one when INFO says "
                  "model_format=words)");
        return;
    }
    if (!kv_ok(image + m.kv_at, m.kv_n)) {
        proto_nack_text(f, NACK_INVALID_MODEL, "words image: its parameter list does not decode");
        return;
    }
    if (m.kind == IMAGE_MODEL) {
        code = name_check(image + m.name_at, m.name_n, &w);
        if (!code) {
            model = words_at(m.model_at, m.model_n);
            code = check_model(model, m.model_n, eng.width, eng.height, &w);
        }
        if (!code && m.ids_count && m.ids_count != (uint32_t)model[0]) {
            b_str(&w, "words image: its tracker ids are not one per tracker");
            code = NACK_INVALID_MODEL;
        }
    } else if (!eng.loaded) {
        b_str(&w, "parameters without a model: load a model first");
        code = NACK_BAD_STATE;
    }
    params = words_at(m.params_at, m.params_n);
    if (!code)
        code = check_params(params, m.params_n, &w);
    if (code) {
        sess.updates_rejected++;
        proto_nack(f, WIRE_VERSION, (uint8_t)code, &w);
        return;
    }
    rc = engine_load(model, m.model_n, params, m.params_n);
    if (rc != 0) {                       /* checked above: a defect if it happens */
        proto_nack_kernel_refused(f, "the kernel refused the words", rc);
        return;
    }
    for (k = 0; k < m.kv_n; k++)
        kv[k] = image[m.kv_at + k];
    kv_n = m.kv_n;
    c_params = params;
    c_params_n = m.params_n;
    if (m.kind == IMAGE_MODEL) {
        c_model = model;
        c_model_n = m.model_n;
        for (k = 0; k < m.name_n; k++)
            name[k] = image[m.name_at + k];
        name_n = m.name_n;
        have_ids = m.ids_count > 0 && m.ids_n <= IDS_MAX;
        if (have_ids)
            for (k = 0; k < m.ids_n; k++)
                ids[k] = image[m.ids_at + k];
        ids_n = m.ids_n;
        ids_count = m.ids_count;
        trackers = (uint32_t)model[0];
        connections = (uint32_t)model[1];
        image_is_model = 1;
    }
    proto_applied(f);
}

void proto_applied(const frame_t *f)
{
    buf_t b = proto_out();
    eng.generation++;
    proto_ack(f, eng.generation);
    b_u32(&b, eng.generation);
    b_u64(&b, (uint64_t)engine_last_t());
    proto_send(MSG_APPLIED, b.p, b.n);
}

int32_t *proto_committed_params(uint32_t *n)
{
    *n = c_params ? c_params_n : 0;
    return c_params;
}

uint8_t *proto_kv(uint32_t **n)
{
    *n = &kv_n;
    return kv;
}

static void on_model_commit(const frame_t *f)
{
    uint32_t k;
    if (f->len != 8) {
        proto_nack_text(f, NACK_MALFORMED, "MODEL_BEGIN/COMMIT: payload is not 8 bytes");
        return;
    }
    if (!up_active) {
        proto_nack_text(f, NACK_BAD_STATE, "MODEL_COMMIT without MODEL_BEGIN");
        return;
    }
    up_active = 0;                       /* the upload state is discarded after every COMMIT */
    if (le32(f->payload) != up_total || le32(f->payload + 4) != up_crc) {
        proto_nack_text(f, NACK_INVALID_MODEL, "MODEL_COMMIT length/CRC differ from MODEL_BEGIN");
        return;
    }
    for (k = 0; k < up_total; k++)
        if (!(have[k >> 3] & (1u << (k & 7)))) {
            proto_nack_text(f, NACK_INVALID_MODEL, "upload incomplete: bytes missing");
            return;
        }
    if (crc32(0, image, up_total) != up_crc) {
        proto_nack_text(f, NACK_INVALID_MODEL, "model CRC-32 mismatch after upload");
        return;
    }
    commit(f);
}

/* ---- run state ---------------------------------------------------------------------------- */
static void on_simple(const frame_t *f)
{
    if (f->len) {
        proto_nack_text(f, NACK_MALFORMED, "expects an empty payload");
        return;
    }
    switch (f->type) {
    case MSG_START:
        if (!eng.loaded) {
            proto_nack_text(f, NACK_BAD_STATE, "no model loaded: upload one first (hostctl load-model)");
            return;
        }
        if (!eng.stream_ok) {
            proto_nack_text(f, NACK_BAD_STATE, "no event stream at the stream region: start the "
                      "image with springtrack mcu run --events FILE");
            return;
        }
        engine_start();
        break;
    case MSG_STOP:
        engine_stop();
        break;
    case MSG_RESET:
        up_active = 0;
        if (eng.loaded) {                /* the model's words, the parameters' now */
            if (!image_is_model || !c_params) {
                proto_nack_text(f, NACK_BAD_STATE, "the model's words were overwritten by an upload "
                          "since it was committed: load the model again to reset");
                return;
            }
            engine_reset();
            engine_load(c_model, c_model_n, c_params, c_params_n);
            eng.generation++;
        }
        break;
    case MSG_ACQUIRE:                    /* firmware_sim's answer without --acquire */
        proto_nack_text(f, NACK_BAD_STATE, "this firmware runs without acquisition: the "
                  "microcontroller image has no acquisition search (docs/mcu.md)");
        return;
    case MSG_SHUTDOWN:
        proto_ack(f, 0);
        {
            buf_t b = proto_out();
            b_u8(&b, NOTICE_SHUTTING_DOWN);
            b_u16(&b, 19);
            b_str(&b, "the firmware halts");
            b_u8(&b, '.');
            proto_send(MSG_NOTICE, b.p, b.n);
        }
        board_halt();
        return;
    default:                             /* HEARTBEAT: a ping */
        break;
    }
    proto_ack(f, 0);
}

/* ---- frames from the host ---------------------------------------------------------------- */
void proto_frame(const frame_t *f)
{
    uint32_t k, crc;
    if (f->version != WIRE_VERSION) {
        version_nack(f, f->version);
        return;
    }
    if (LINK_KEY_LEN && f->type != MSG_HELLO) {
        if (!signature_ok(f))            /* dropped, counted, no answer (no oracle) */
            return;
        sess.authenticated = 1;
    } else if (!LINK_KEY_LEN && (f->flags & WIRE_FLAG_SIGNED)) {
        proto_nack_text(f, NACK_BAD_STATE, "signed frame on a link without a key: the tag cannot "
                  "be checked, refused");
        return;
    }
    crc = crc32(0, f->payload, f->len);
    for (k = 0; k < CACHE; k++)          /* a retry of an ACKed command: answer again */
        if (cache[k].used && cache[k].seq == f->seq && cache[k].type == f->type
            && cache[k].crc == crc && f->type != MSG_HELLO) {
            buf_t b = proto_out();
            b_u16(&b, f->seq);
            b_u8(&b, f->type);
            b_u32(&b, cache[k].value);
            sess.retries++;
            proto_send(MSG_ACK, b.p, b.n);
            return;
        }
    if (f->type == MSG_HELLO) {
        sess.rx_last = f->seq;
    } else if (sess.rx_last >= 0) {
        uint32_t gap = ((uint32_t)f->seq - (uint32_t)sess.rx_last - 1u) & 0xFFFFu;
        if (gap != 0xFFFFu) {
            sess.rx_last = f->seq;
            if (gap < 0x8000u)
                sess.rx_lost += gap;
        }
    } else {
        sess.rx_last = f->seq;
    }
    if (!wire_host_command(f->type)) {
        buf_t w = proto_why();
        static const char hex[] = "0123456789abcdef";
        b_str(&w, "message type 0x");
        b_u8(&w, (uint8_t)hex[f->type >> 4]);
        b_u8(&w, (uint8_t)hex[f->type & 15]);
        b_str(&w, " is not a host command");
        proto_nack(f, WIRE_VERSION, NACK_UNKNOWN_TYPE, &w);
        return;
    }
    if (!wire_monitor_command(f->type) && !(sess.session && sess.role == ROLE_OPERATOR)) {
        sess.forbidden++;
        proto_nack_text(f, NACK_FORBIDDEN, sess.session ? "this session is a monitor (read-only); "
                  "HELLO as operator to take over" : "no session: send HELLO first");
        return;
    }
    switch (f->type) {
    case MSG_HELLO: on_hello(f); break;
    case MSG_MODEL_BEGIN: on_model_begin(f); break;
    case MSG_MODEL_CHUNK: on_model_chunk(f); break;
    case MSG_MODEL_COMMIT: on_model_commit(f); break;
    case MSG_PARAM_GET: on_param_get(f); break;
    case MSG_STATS: on_stats(f); break;
    case MSG_MODEL_GET:                  /* words only: no TOML to give back */
        proto_nack_text(f, NACK_BAD_STATE, "MODEL_GET: this firmware holds its model as words "
                  "(model_format=words), not as TOML: the host that uploaded it has the text");
        break;
    case MSG_PARAM_SET: on_param_set(f); break;
    default: on_simple(f); break;
    }
}

void proto_init(void)
{
    sess.rx_last = -1;
    sess.tx_seq = (uint16_t)(board_ticks() * 2654435761u >> 16);
}
