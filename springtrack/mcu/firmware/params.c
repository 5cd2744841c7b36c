/* PARAM_SET by name: firmware_sim's Engine.set_param on the core.  The name, type and
 * range of the value are checked against springtrack.params.SPECS (param_specs.h,
 * generated from it), then the whole set as springtrack.params.Params, springtrack.limits
 * and the fixed kernel check it (sigma_min_px < sigma_max_px, the covariance gain of
 * eq. (4), no motion model), with their NACK codes; nothing changes unless every check
 * passes.  The kernel's words are then computed from the values as
 * springtrack.fixed.q.params_q computes them, with the host's double arithmetic
 * (xfloat.h: the same roundings; exp and log to the nearest double, where the host's libm
 * may differ by one ulp), and loaded between two batches of events. */
#include "board.h"
#include "engine.h"
#include "fixed_step.h"
#include "param_words.h"
#include "proto.h"

extern fx_state mcu_state[];            /* entry.c: the kernel's state */

/* well-formed UTF-8 (what Python's decode accepts: no overlong forms or surrogates) */
static int utf8_ok(const uint8_t *p, uint32_t n)
{
    uint32_t i = 0, k, len, cp;
    while (i < n) {
        uint8_t c = p[i];
        if (c < 0x80) {
            i++;
            continue;
        }
        len = c >= 0xF0 ? 4 : c >= 0xE0 ? 3 : c >= 0xC2 ? 2 : 0;
        if (!len || c > 0xF4 || i + len > n)
            return 0;
        cp = c & (0x7Fu >> len);
        for (k = 1; k < len; k++) {
            if ((p[i + k] & 0xC0) != 0x80)
                return 0;
            cp = cp << 6 | (p[i + k] & 0x3Fu);
        }
        if ((len == 3 && (cp < 0x800 || (cp >= 0xD800 && cp < 0xE000)))
            || (len == 4 && (cp < 0x10000 || cp > 0x10FFFF)))
            return 0;
        i += len;
    }
    return 1;
}

/* the current values from the committed key/value list; 0 if one is missing */
static int read_values(values_t *v)
{
    uint32_t *n, pos = 1, c, have = 0, s;
    const uint8_t *kv = proto_kv(&n);
    int k;
    for (c = 0; *n && c < kv[0]; c++) {
        const uint8_t *e = kv + pos;
        s = entry_size(e, *n - pos);
        if (!s)
            return 0;
        k = param_lookup(e + 1, e[0]);
        if (k >= 0) {
            const uint8_t *val = e + 2 + e[0];
            uint8_t tag = e[1 + e[0]];
            if (param_specs[k].kind == PARAM_FLOAT && tag == 'f')
                v->f[k] = param_rd64(val);
            else if (param_specs[k].kind == PARAM_INT && tag == 'i')
                v->i[k] = (int64_t)param_rd64(val);
            else if (param_specs[k].kind == PARAM_STR && tag == 's'
                     && (v->i[k] = param_choice(k, val + 1, val[0])) >= 0)
                ;
            else
                return 0;
            have |= 1u << k;
        }
        pos += s;
    }
    return have == (1u << PARAM_COUNT) - 1;
}

/* the key/value list with entry k's value replaced by the checked one (in place) */
static void kv_update(int k, const values_t *v)
{
    uint32_t *n, pos = 1, c, s, at = 0, size = 0, j;
    uint8_t *kv = proto_kv(&n), e[12 + 256];
    uint32_t en = 0, nl = 0;
    for (c = 0; c < kv[0]; c++) {
        s = entry_size(kv + pos, *n - pos);
        if (param_lookup(kv + pos + 1, kv[pos]) == k) {
            at = pos;
            size = s;
            nl = kv[pos];
        }
        pos += s;
    }
    for (j = 0; j <= nl; j++)           /* the name, then the typed value */
        e[en++] = kv[at + j];
    if (param_specs[k].kind == PARAM_STR) {
        const char *t = param_specs[k].choices[v->i[k]];
        e[en++] = 's';
        for (j = 0; t[j]; j++)
            e[en + 1 + j] = (uint8_t)t[j];
        e[en] = (uint8_t)j;
        en += 1 + j;
    } else {
        uint64_t x = param_specs[k].kind == PARAM_FLOAT ? v->f[k] : (uint64_t)v->i[k];
        e[en++] = param_specs[k].kind == PARAM_FLOAT ? 'f' : 'i';
        for (j = 0; j < 8; j++)
            e[en++] = (uint8_t)(x >> (8 * j));
    }
    if (en > size)                       /* the tail moves up, or down */
        for (j = *n; j-- > at + size;)
            kv[j + en - size] = kv[j];
    else
        for (j = at + size; j < *n; j++)
            kv[j + en - size] = kv[j];
    for (j = 0; j < en; j++)
        kv[at + j] = e[j];
    *n = *n + en - size;
}

void on_param_set(const frame_t *f)
{
    const uint8_t *p = f->payload;
    uint32_t nl, vl, nw;
    uint8_t tag;
    int k, code, rc;
    uint32_t t0;
    values_t v, old;
    int32_t *words, nc = mcu_state[0].nc;
    buf_t w = proto_why();
    /* wire.decode_param_set: str8 name, a type tag, the value, nothing after */
    if (f->len < 2 || f->len < 2u + p[0]) {
        proto_nack_text(f, NACK_MALFORMED, "PARAM_SET: truncated");
        return;
    }
    nl = p[0];
    tag = p[1 + nl];
    vl = tag == 'b' ? 1 : tag == 'i' || tag == 'f' ? 8 : tag == 's' && f->len > 2 + nl
        ? 1u + p[2 + nl] : 0;
    if (!vl || f->len != 2 + nl + vl || (tag == 'b' && p[2 + nl] > 1)
        || !utf8_ok(p + 1, nl) || (tag == 's' && !utf8_ok(p + 3 + nl, vl - 1))) {
        proto_nack_text(f, NACK_MALFORMED, "PARAM_SET: not a name and a typed value "
                        "(wire.encode_param_set)");
        return;
    }
    if (!eng.loaded || !read_values(&v)) {
        proto_nack_text(f, NACK_BAD_STATE, "no model loaded: upload one first (hostctl load-model)");
        return;
    }
    k = param_lookup(p + 1, nl);
    if (k < 0) {
        b_str(&w, "unknown parameter '");
        b_bytes(&w, p + 1, nl);
        b_str(&w, "'; known: ");
        for (k = 0; k < PARAM_COUNT; k++) {
            b_str(&w, param_specs[k].name);
            b_str(&w, k + 1 < PARAM_COUNT ? ", " : "");
        }
        code = NACK_UNKNOWN_NAME;
    } else {
        code = param_check_value(k, tag, p + 2 + nl, &v, &w);
        if (!code)
            code = param_check_set(&v, nc, &w);
    }
    if (code) {
        sess.updates_rejected++;
        proto_nack(f, WIRE_VERSION, (uint8_t)code, &w);
        return;
    }
    words = proto_committed_params(&nw);
    if (!words || nw != Q_PARAMS_WORDS) {
        proto_nack_text(f, NACK_BAD_STATE, "the parameters' words were overwritten by an upload "
                        "since they were committed: load the model again");
        return;
    }
    t0 = board_ticks();
    param_words(&v, nc, words, k == PARAM_ACTIVITY_TAU_US);    /* the tables: tau's */
    sess.param_ticks = (t0 - board_ticks()) & 0xFFFFFFu;      /* SysTick counts down */
    rc = engine_load(0, 0, words, nw);
    if (rc) {                            /* checked above: a defect if it happens */
        read_values(&old);               /* the kv list still holds them */
        param_words(&old, nc, words, 1);
        engine_load(0, 0, words, nw);
        proto_nack_kernel_refused(f, "the kernel refused the parameter words", rc);
        return;
    }
    kv_update(k, &v);
    proto_applied(f);
}
