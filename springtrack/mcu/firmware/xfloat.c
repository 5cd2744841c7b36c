/* xfloat.h: doubles in integers.  A value is unpacked to (sign, m, e, sticky): m * 2^e
 * with the top bit of the 64-bit m set, `sticky` when bits below m are not zero; packing
 * rounds m to 53 bits, to nearest, ties to even, the sticky bit deciding a tie.  exp and
 * log work on the same 64-bit mantissas, truncating (about 2^-60 after their ~25 steps),
 * and round once to a double at the end. */
#include "xfloat.h"
#include "param_specs.h"

typedef struct {
    uint64_t m;
    int32_t e, neg, sticky;
} unp_t;

/* a * b as 128 bits */
static void mul128(uint64_t a, uint64_t b, uint64_t *hi, uint64_t *lo)
{
    uint64_t al = (uint32_t)a, ah = a >> 32, bl = (uint32_t)b, bh = b >> 32;
    uint64_t ll = al * bl, lh = al * bh, hl = ah * bl, hh = ah * bh;
    uint64_t mid = (ll >> 32) + (uint32_t)lh + (uint32_t)hl;
    *lo = (mid << 32) | (uint32_t)ll;
    *hi = hh + (lh >> 32) + (hl >> 32) + (mid >> 32);
}

static unp_t unpack(dbits_t x)
{
    unp_t u = {0, 0, (int32_t)(x >> 63), 0};
    uint32_t ex = (uint32_t)(x >> 52) & 0x7FFu;
    uint64_t frac = x & 0xFFFFFFFFFFFFFull;
    if (ex == 0 && frac == 0)
        return u;
    u.m = (frac | (ex ? 1ull << 52 : 0)) << 11;
    u.e = (int32_t)(ex ? ex : 1) - 1023 - 52 - 11;
    while (!(u.m >> 63)) {               /* a subnormal input */
        u.m <<= 1;
        u.e--;
    }
    return u;
}

static unp_t normalise(unp_t u)
{
    if (u.m == 0)
        return u;
    while (!(u.m >> 63)) {
        u.m <<= 1;
        u.e--;
    }
    return u;
}

static dbits_t pack(unp_t u)
{
    uint64_t q, rem;
    int32_t ex;
    u = normalise(u);
    if (u.m == 0)
        return (uint64_t)u.neg << 63;
    q = u.m >> 11;
    rem = u.m & 0x7FFu;
    if (rem > 0x400u || (rem == 0x400u && (u.sticky || (q & 1))))
        q++;
    ex = u.e + 11 + 52 + 1023;
    if (q >> 53) {
        q >>= 1;
        ex++;
    }
    if (ex <= 0)                         /* below the normal range: not met (see xfloat.h) */
        return (uint64_t)u.neg << 63;
    if (ex >= 0x7FF)
        return (uint64_t)u.neg << 63 | 0x7FF0000000000000ull;
    return (uint64_t)u.neg << 63 | (uint64_t)ex << 52 | (q & 0xFFFFFFFFFFFFFull);
}

/* a b to 64 bits, normalised; *lo: the 64 bits below */
static unp_t product(unp_t a, unp_t b, uint64_t *lo)
{
    unp_t r = {0, 0, a.neg ^ b.neg, 0};
    uint64_t hi;
    *lo = 0;
    if (a.m == 0 || b.m == 0)
        return r;
    mul128(a.m, b.m, &hi, lo);
    r.e = a.e + b.e + 64;
    if (!(hi >> 63)) {
        hi = hi << 1 | *lo >> 63;
        *lo <<= 1;
        r.e--;
    }
    r.m = hi;
    return r;
}

dbits_t d_mul(dbits_t a, dbits_t b)
{
    uint64_t lo;
    unp_t r = product(unpack(a), unpack(b), &lo);
    r.sticky = lo != 0;
    return pack(r);
}

/* quotient bits of a / b, mantissas below 2^63: 64 bits of floor(a / b 2^63), sticky */
static uint64_t divide(uint64_t a, uint64_t b, int32_t *sticky)
{
    uint64_t q = 0;
    int i;
    for (i = 0; i < 64; i++) {
        q <<= 1;
        if (a >= b) {
            a -= b;
            q |= 1;
        }
        a <<= 1;
    }
    *sticky = a != 0;
    return q;
}

dbits_t d_div(dbits_t a, dbits_t b)
{
    unp_t x = unpack(a), y = unpack(b), r = {0, 0, x.neg ^ y.neg, 0};
    if (x.m == 0)
        return (uint64_t)r.neg << 63;
    r.m = divide(x.m >> 1, y.m >> 1, &r.sticky);     /* the low bits are 0: nothing lost */
    r.e = x.e - y.e - 63;
    return pack(r);
}

/* *x and *y swapped if need be so that |*x| >= |*y| */
static void larger_first(unp_t *x, unp_t *y)
{
    if (x->e < y->e || (x->e == y->e && x->m < y->m)) {
        unp_t r = *x;
        *x = *y;
        *y = r;
    }
}

static unp_t add(unp_t x, unp_t y)
{
    unp_t r;
    int32_t d, sticky = 0;
    if (y.m == 0)
        return x;
    if (x.m == 0)
        return y;
    larger_first(&x, &y);
    x.m >>= 1;                           /* room for the carry */
    y.m >>= 1;
    x.e++;
    y.e++;
    d = x.e - y.e;
    if (d >= 64) {
        sticky = y.m != 0;
        y.m = 0;
    } else if (d > 0) {
        sticky = (y.m & ((1ull << d) - 1)) != 0;
        y.m >>= d;
    }
    sticky |= x.sticky | y.sticky;
    r = x;
    if (x.neg == y.neg) {
        r.m = x.m + y.m;
    } else {
        r.m = x.m - y.m - (sticky ? 1 : 0);          /* the lost bits are a borrow */
        if (r.m == 0 && !sticky)
            r.neg = 0;                   /* x - x = +0 */
    }
    r.sticky = sticky;
    return normalise(r);
}

dbits_t d_add(dbits_t a, dbits_t b) { return pack(add(unpack(a), unpack(b))); }
dbits_t d_sub(dbits_t a, dbits_t b) { return d_add(a, D_NEG(b)); }

static int64_t order(dbits_t a)
{
    int64_t m = (int64_t)(a & 0x7FFFFFFFFFFFFFFFull);
    return a >> 63 ? -m : m;
}

int d_lt(dbits_t a, dbits_t b) { return order(a) < order(b); }
int d_le(dbits_t a, dbits_t b) { return order(a) <= order(b); }
int d_finite(dbits_t a) { return ((a >> 52) & 0x7FFu) != 0x7FFu; }

dbits_t d_from_int(int64_t v)
{
    unp_t u = {v < 0 ? (uint64_t)0 - (uint64_t)v : (uint64_t)v, 0, v < 0, 0};
    return pack(u);
}

int64_t d_round_scaled(dbits_t x, int k)
{
    unp_t u = unpack(x);
    int32_t sh = -(u.e + k);             /* value = m 2^-sh, sh >= 1 for |value| < 2^63 */
    uint64_t q, rem, half;
    if (u.m == 0 || sh > 64)
        return 0;
    if (sh < 1)                          /* |value| >= 2^63: saturated */
        return u.neg ? INT64_MIN : INT64_MAX;
    q = sh == 64 ? 0 : u.m >> sh;
    rem = sh == 64 ? u.m : u.m & ((1ull << sh) - 1);
    half = 1ull << (sh - 1);
    if (rem > half || (rem == half && (q & 1)))
        q++;
    if (q >> 63)                         /* rounded up to 2^63: saturated */
        return u.neg ? INT64_MIN : INT64_MAX;
    return u.neg ? -(int64_t)q : (int64_t)q;
}

int d_ilogb(dbits_t x)
{
    unp_t u = unpack(x);
    return u.e + 63;
}

/* ---- exp and log on 64-bit mantissas (signed, truncating) -------------------------------- */
static unp_t xc(xconst_t c)
{
    unp_t u = {c.m, c.e, 0, 0};
    return u;
}

/* a b, rounded to 64 bits */
static unp_t xmul(unp_t a, unp_t b)
{
    uint64_t lo;
    unp_t r = product(a, b, &lo);
    r.m += lo >> 63;
    if (r.m == 0 && (lo >> 63)) {        /* rounded up to 2^64 */
        r.m = 1ull << 63;
        r.e++;
    }
    return r;
}

static unp_t xint(int32_t k)
{
    unp_t u = {(uint64_t)(k < 0 ? -k : k), 0, k < 0, 0};
    return normalise(u);
}

/* a + b, rounded to 64 bits */
static unp_t xadd(unp_t a, unp_t b)
{
    unp_t r;
    uint64_t bm, s;
    int32_t d;
    if (b.m == 0)
        return a;
    if (a.m == 0)
        return b;
    larger_first(&a, &b);
    d = a.e - b.e;
    bm = d == 0 ? b.m : d < 64 ? (b.m >> d) + ((b.m >> (d - 1)) & 1) : d == 64 ? b.m >> 63 : 0;
    r = a;
    if (a.neg == b.neg) {
        s = a.m + bm;
        if (s < a.m) {                   /* carry: 65 bits, rounded to 64 */
            s = (s >> 1 | 1ull << 63) + (s & 1);
            r.e++;
        }
        r.m = s;
        return r;
    }
    r.m = a.m - bm;
    return normalise(r);
}

dbits_t d_exp_neg(dbits_t x)
{
    unp_t r = unpack(x), y, s;
    int32_t k = 0, i, sh;
    unp_t t = xmul(r, xc(X_INV_LN2));    /* x / ln 2, then k its nearest integer */
    if (t.m && t.e > -64) {
        sh = -t.e - 1;
        k = (int32_t)(((sh >= 64 ? 0 : t.m >> sh) + 1) >> 1);
    }
    if (k) {                             /* r = x - k ln 2, |r| <= ln 2 / 2: k ln2_hi */
        unp_t hi = xmul(xint(k), xc(X_LN2_HI)), lo = xmul(xint(k), xc(X_LN2_LO));
        hi.neg ^= 1;                     /* is exact, and so is x - k ln2_hi */
        lo.neg ^= 1;
        r = xadd(xadd(r, hi), lo);
    }
    y = r;                               /* exp(-r) = sum (-r)^i / i!, by Horner */
    y.neg ^= 1;
    s = xc(X_INV_FACT[X_EXP_TERMS - 1]);
    for (i = X_EXP_TERMS - 2; i >= 0; i--)
        s = xadd(xmul(s, y), xc(X_INV_FACT[i]));
    s.e -= k;
    return pack(s);
}

dbits_t d_log(dbits_t x)
{
    unp_t u = unpack(x), num, den, z, w, s, res;
    int32_t e = u.e + 63, i;             /* x = M 2^e, M in [0.75, 1.5) */
    unp_t one = {1ull << 63, -63, 0, 0};
    u.e = -63;
    if (u.m >= 0xC000000000000000ull) {
        u.e--;
        e++;
    }
    num = u;
    one.neg = 1;
    num = xadd(u, one);                  /* M - 1, exact */
    one.neg = 0;
    den = xadd(u, one);                  /* M + 1, exact */
    res = xmul(xint(e), xc(X_LN2));
    if (num.m == 0)
        return pack(res);
    z.neg = num.neg;                     /* z = (M - 1) / (M + 1), |z| <= 1/5 */
    z.sticky = 0;
    z.m = divide(num.m >> 1, den.m >> 1, &i);
    z.e = num.e - den.e - 63;
    z = normalise(z);
    w = xmul(z, z);                      /* ln M = 2 z sum w^k / (2k + 1) */
    s = xc(X_INV_ODD[X_ATANH_TERMS - 1]);
    for (i = X_ATANH_TERMS - 2; i >= 0; i--)
        s = xadd(xmul(s, w), xc(X_INV_ODD[i]));
    s = xmul(s, z);
    s.e++;
    return pack(e ? xadd(res, s) : s);
}
