/* The hand-vectorised peer tracker (see peer.h): eq. (2) over the index's candidates with
 * AVX-512 (eight trackers a lane-block, the candidate mask as the lanes' write mask) or,
 * where the build's -march has no AVX-512, AVX2 (four a block, the mask through a table);
 * no branch per tracker.  The spring passes four connections at a time with AVX2 (gathers,
 * a vector atan2 and sincos after Cephes, the terms of eqs. 10-20 branch-free); the scatter
 * onto the trackers and the energy criteria stay scalar.  Built with -march=native and
 * -ffp-contract=off: the same rounding as the plain peer's products and sums. */
#include <immintrin.h>

#include "peer.h"

#if defined(__AVX512F__)
/* eq. (2): the lowest-index candidate with the smallest d^2 below the gate, or -1.  A lane
 * keeps its first minimum (strict <), so equal d^2 resolve to the lowest index as in the
 * reference's scan; d^2 is the one eq. (2)'s probability is computed from. */
static inline int scan(const Peer *s, uint64_t cand, double fx, double fy, double *d2_out)
{
    const __m512d X = _mm512_set1_pd(fx), Y = _mm512_set1_pd(fy);
    __m512d best = _mm512_set1_pd(s->gate);
    __m512i idx = _mm512_set1_epi64(-1), lane = _mm512_setr_epi64(0, 1, 2, 3, 4, 5, 6, 7);
    const __m512i eight = _mm512_set1_epi64(8);
    if (!cand)                              /* decided by the cell's mask alone */
        return -1;
    int nb = (s->n + 7) >> 3;
    for (int b = 0; b < nb; b++) {
        __mmask8 km = (__mmask8)(cand >> (8 * b));
        __m512d dx = _mm512_sub_pd(X, _mm512_load_pd(s->mx + 8 * b));
        __m512d dy = _mm512_sub_pd(Y, _mm512_load_pd(s->my + 8 * b));
        __m512d d2 = _mm512_add_pd(
            _mm512_add_pd(_mm512_mul_pd(_mm512_mul_pd(_mm512_load_pd(s->ia + 8 * b), dx), dx),
                          _mm512_mul_pd(_mm512_mul_pd(_mm512_load_pd(s->ic + 8 * b), dy), dy)),
            _mm512_mul_pd(_mm512_mul_pd(_mm512_load_pd(s->ib2 + 8 * b), dx), dy));
        __mmask8 lt = _mm512_mask_cmp_pd_mask(km, d2, best, _CMP_LT_OQ);
        best = _mm512_mask_mov_pd(best, lt, d2);
        idx = _mm512_mask_mov_epi64(idx, lt, lane);
        lane = _mm512_add_epi64(lane, eight);
    }
    /* the minimum across the lanes; the lane holding it (one lane but for exact ties,
     * which take the lowest index of the lanes that hold it) */
    __m512d m = _mm512_min_pd(best, _mm512_shuffle_f64x2(best, best, 0x4e));
    m = _mm512_min_pd(m, _mm512_shuffle_f64x2(m, m, 0xb1));
    m = _mm512_min_pd(m, _mm512_permute_pd(m, 0x55));
    double d2 = _mm512_cvtsd_f64(m);
    if (!(d2 < s->gate))
        return -1;
    __mmask8 at = _mm512_cmp_pd_mask(best, m, _CMP_EQ_OQ);
    *d2_out = d2;
    _Alignas(64) int64_t lanes[8];
    _mm512_store_si512(lanes, idx);
    if (__builtin_expect((at & (at - 1)) == 0, 1))
        return (int)lanes[__builtin_ctz(at)];
    return (int)_mm512_mask_reduce_min_epi64(at, idx);
}

/* tracker i's lane of a block written as the whole block (see store_tracker) */
#define BLOCK 8
#define LANE_MASK(i) __mmask8 on = (__mmask8)(1u << ((i) & 7))
#define STORE_LANE(arr, o, v)                                                            \
    _mm512_store_pd(arr + o, _mm512_mask_mov_pd(_mm512_load_pd(arr + o), on, _mm512_set1_pd(v)))
const char *peer_isa(void) { return "AVX-512 scan, AVX2 springs"; }
#else
/* the lanes of a block of four whose candidate bit is set: all ones */
static const int64_t LANE_MASKS[16][4] __attribute__((aligned(32))) = {
#define M(b) ((b) ? -1LL : 0LL)
#define ROW(v) {M((v) & 1), M((v) & 2), M((v) & 4), M((v) & 8)}
    ROW(0), ROW(1), ROW(2), ROW(3), ROW(4), ROW(5), ROW(6), ROW(7),
    ROW(8), ROW(9), ROW(10), ROW(11), ROW(12), ROW(13), ROW(14), ROW(15)
#undef ROW
#undef M
};

/* eq. (2) as above, four trackers a block: a lane outside the candidates reads +inf */
static inline int scan(const Peer *s, uint64_t cand, double fx, double fy, double *d2_out)
{
    const __m256d X = _mm256_set1_pd(fx), Y = _mm256_set1_pd(fy), INF = _mm256_set1_pd(INFINITY);
    __m256d best = _mm256_set1_pd(s->gate), idx = _mm256_set1_pd(-1.0);
    __m256d lane = _mm256_setr_pd(0, 1, 2, 3);
    if (!cand)                              /* decided by the cell's mask alone */
        return -1;
    int nb = ((63 - __builtin_clzll(cand)) >> 2) + 1;       /* up to the last candidate */
    for (int b = 0; b < nb; b++) {
        __m256d on = _mm256_load_pd((const double *)LANE_MASKS[(cand >> (4 * b)) & 15]);
        __m256d dx = _mm256_sub_pd(X, _mm256_load_pd(s->mx + 4 * b));
        __m256d dy = _mm256_sub_pd(Y, _mm256_load_pd(s->my + 4 * b));
        __m256d d2 = _mm256_add_pd(
            _mm256_add_pd(_mm256_mul_pd(_mm256_mul_pd(_mm256_load_pd(s->ia + 4 * b), dx), dx),
                          _mm256_mul_pd(_mm256_mul_pd(_mm256_load_pd(s->ic + 4 * b), dy), dy)),
            _mm256_mul_pd(_mm256_mul_pd(_mm256_load_pd(s->ib2 + 4 * b), dx), dy));
        d2 = _mm256_blendv_pd(INF, d2, on);
        __m256d lt = _mm256_cmp_pd(d2, best, _CMP_LT_OQ);
        best = _mm256_blendv_pd(best, d2, lt);
        idx = _mm256_blendv_pd(idx, lane, lt);
        lane = _mm256_add_pd(lane, _mm256_set1_pd(4.0));
    }
    __m256d m = _mm256_min_pd(best, _mm256_permute2f128_pd(best, best, 1));
    m = _mm256_min_pd(m, _mm256_permute_pd(m, 5));
    double d2 = _mm256_cvtsd_f64(m);
    if (!(d2 < s->gate))
        return -1;
    __m256d c = _mm256_blendv_pd(_mm256_set1_pd(1e9), idx, _mm256_cmp_pd(best, m, _CMP_EQ_OQ));
    c = _mm256_min_pd(c, _mm256_permute2f128_pd(c, c, 1));
    c = _mm256_min_pd(c, _mm256_permute_pd(c, 5));
    *d2_out = d2;
    return (int)_mm256_cvtsd_f64(c);
}

/* tracker i's lane of a block written as the whole block (see store_tracker) */
#define BLOCK 4
#define LANE_MASK(i) __m256d on = _mm256_load_pd((const double *)LANE_MASKS[1 << ((i) & 3)])
#define STORE_LANE(arr, o, v)                                                            \
    _mm256_store_pd(arr + o, _mm256_blendv_pd(_mm256_load_pd(arr + o), _mm256_set1_pd(v), on))
const char *peer_isa(void) { return "AVX2"; }
#endif

/* What scan() reads of tracker i, its lane written as a whole block (load, blend, store):
 * the next event's block loads then forward from one store of their width, where a scalar
 * store into the block would stall them (a wide load cannot forward from a narrower store). */
static inline void store_tracker(Peer *s, int i, double x, double y, double ia, double ib2,
                                 double ic)
{
    int o = i & ~(BLOCK - 1);
    LANE_MASK(i);
    STORE_LANE(s->mx, o, x);
    STORE_LANE(s->my, o, y);
    STORE_LANE(s->ia, o, ia);
    STORE_LANE(s->ib2, o, ib2);
    STORE_LANE(s->ic, o, ic);
}

/* ---- vector elementary functions (Cephes' atan, sin and cos; about 1 ulp) ---- */
#define V(c) _mm256_set1_pd(c)
static inline __m256d vsel(__m256d mask, __m256d a, __m256d b) { return _mm256_blendv_pd(b, a, mask); }
static inline __m256d vabs(__m256d x) { return _mm256_andnot_pd(V(-0.0), x); }

/* atan2(y, x) in [-pi, pi]; atan2(0, 0) = 0 */
static inline __m256d vatan2(__m256d y, __m256d x)
{
    const double MOREBITS = 6.123233995736765886130e-17;
    __m256d ax = vabs(x), ay = vabs(y);
    __m256d num = _mm256_min_pd(ax, ay), den = _mm256_max_pd(ax, ay);
    __m256d big = _mm256_cmp_pd(num, _mm256_mul_pd(V(0.66), den), _CMP_GT_OQ);
    /* t in [0, 1]; above 0.66: atan t = pi/4 + atan((t - 1) / (t + 1)), one division */
    __m256d tn = vsel(big, _mm256_sub_pd(num, den), num);
    __m256d td = vsel(big, _mm256_add_pd(num, den), den);
    td = vsel(_mm256_cmp_pd(td, V(0.0), _CMP_EQ_OQ), V(1.0), td);
    __m256d t = _mm256_div_pd(tn, td), z = _mm256_mul_pd(t, t);
    __m256d p = V(-8.750608600031904122785e-1);
    p = _mm256_add_pd(_mm256_mul_pd(p, z), V(-1.615753718733365076637e1));
    p = _mm256_add_pd(_mm256_mul_pd(p, z), V(-7.500855792314704667340e1));
    p = _mm256_add_pd(_mm256_mul_pd(p, z), V(-1.228866684490136173410e2));
    p = _mm256_add_pd(_mm256_mul_pd(p, z), V(-6.485021904942025371773e1));
    __m256d q = _mm256_add_pd(z, V(2.485846490142306297962e1));
    q = _mm256_add_pd(_mm256_mul_pd(q, z), V(1.650270098316988542046e2));
    q = _mm256_add_pd(_mm256_mul_pd(q, z), V(4.328810604912902668951e2));
    q = _mm256_add_pd(_mm256_mul_pd(q, z), V(4.853903996359136964868e2));
    q = _mm256_add_pd(_mm256_mul_pd(q, z), V(1.945506571482613964425e2));
    __m256d r = _mm256_add_pd(_mm256_mul_pd(t, _mm256_div_pd(_mm256_mul_pd(z, p), q)), t);
    r = _mm256_add_pd(vsel(big, V(M_PI_4), V(0.0)),
                      _mm256_add_pd(r, vsel(big, V(0.5 * MOREBITS), V(0.0))));
    /* |y| > |x|: pi/2 - r; x < 0: pi - r; then the sign of y */
    r = vsel(_mm256_cmp_pd(ay, ax, _CMP_GT_OQ),
             _mm256_add_pd(_mm256_sub_pd(V(M_PI_2), r), V(MOREBITS)), r);
    r = vsel(_mm256_cmp_pd(x, V(0.0), _CMP_LT_OQ),
             _mm256_add_pd(_mm256_sub_pd(V(M_PI), r), V(2.0 * MOREBITS)), r);
    return _mm256_or_pd(r, _mm256_and_pd(y, V(-0.0)));
}

/* sin x and cos x (Cephes' reduction by pi/4 in three parts, degree-6 polynomials) */
static inline void vsincos(__m256d x, __m256d *sn, __m256d *cs)
{
    __m256d sign_x = _mm256_and_pd(x, V(-0.0)), ax = vabs(x);
    __m128i j = _mm256_cvttpd_epi32(_mm256_mul_pd(ax, V(1.27323954473516268615)));
    j = _mm_and_si128(_mm_add_epi32(j, _mm_set1_epi32(1)), _mm_set1_epi32(~1));
    __m256d y = _mm256_cvtepi32_pd(j);
    __m256d z = _mm256_sub_pd(ax, _mm256_mul_pd(y, V(7.85398125648498535156e-1)));
    z = _mm256_sub_pd(z, _mm256_mul_pd(y, V(3.77489470793079817668e-8)));
    z = _mm256_sub_pd(z, _mm256_mul_pd(y, V(2.69515142907905952645e-15)));
    __m256d zz = _mm256_mul_pd(z, z);
    __m256d ps = V(1.58962301576546568060e-10);
    ps = _mm256_add_pd(_mm256_mul_pd(ps, zz), V(-2.50507477628578072866e-8));
    ps = _mm256_add_pd(_mm256_mul_pd(ps, zz), V(2.75573136213857245213e-6));
    ps = _mm256_add_pd(_mm256_mul_pd(ps, zz), V(-1.98412698295895385996e-4));
    ps = _mm256_add_pd(_mm256_mul_pd(ps, zz), V(8.33333333332211858878e-3));
    ps = _mm256_add_pd(_mm256_mul_pd(ps, zz), V(-1.66666666666666307295e-1));
    ps = _mm256_add_pd(z, _mm256_mul_pd(_mm256_mul_pd(z, zz), ps));
    __m256d pc = V(-1.13585365213876817300e-11);
    pc = _mm256_add_pd(_mm256_mul_pd(pc, zz), V(2.08757008419747316778e-9));
    pc = _mm256_add_pd(_mm256_mul_pd(pc, zz), V(-2.75573141792967388112e-7));
    pc = _mm256_add_pd(_mm256_mul_pd(pc, zz), V(2.48015872888517045348e-5));
    pc = _mm256_add_pd(_mm256_mul_pd(pc, zz), V(-1.38888888888730564116e-3));
    pc = _mm256_add_pd(_mm256_mul_pd(pc, zz), V(4.16666666666665929218e-2));
    pc = _mm256_add_pd(_mm256_sub_pd(V(1.0), _mm256_mul_pd(V(0.5), zz)),
                       _mm256_mul_pd(_mm256_mul_pd(zz, zz), pc));
    /* octant j (even): j & 2 swaps the polynomials; sin flips sign for j & 4, cos for
     * j in {2, 4} (mod 8) */
    __m256i j64 = _mm256_cvtepi32_epi64(j);
    __m256d swap = _mm256_castsi256_pd(
        _mm256_cmpeq_epi64(_mm256_and_si256(j64, _mm256_set1_epi64x(2)), _mm256_set1_epi64x(2)));
    __m256d fs = _mm256_castsi256_pd(_mm256_slli_epi64(j64, 61));
    __m256d fc = _mm256_xor_pd(fs, _mm256_castsi256_pd(_mm256_slli_epi64(j64, 62)));
    *sn = _mm256_xor_pd(vsel(swap, pc, ps), _mm256_and_pd(_mm256_xor_pd(fs, sign_x), V(-0.0)));
    *cs = _mm256_xor_pd(vsel(swap, ps, pc), _mm256_and_pd(fc, V(-0.0)));
}

static inline __m256d vhsum(__m256d v)
{
    __m256d h = _mm256_add_pd(v, _mm256_permute2f128_pd(v, v, 1));
    return _mm256_add_pd(h, _mm256_permute_pd(h, 5));
}

/* eqs. (10)-(20) four connections at a time; connections past nc are padding (ends 0 and
 * 0, stiffness 0: no energy, no displacement, a zero angle). */
static void springs(Peer *s)
{
    int nc = s->nc, nb = (nc + 3) / 4;
    _Alignas(32) double rxs[PEER_MAX_C], rys[PEER_MAX_C], dth[PEER_MAX_C];
    _Alignas(32) double uax[PEER_MAX_C], uay[PEER_MAX_C], ubx[PEER_MAX_C], uby[PEER_MAX_C];
    double ddx[PEER_MAX_T] = {0}, ddy[PEER_MAX_T] = {0};
    __m256d sum = V(0.0);
    for (int b = 0; b < nb; b++) {                                  /* gather r = b - a */
        __m128i ia = _mm_load_si128((const __m128i *)(s->ca + 4 * b));
        __m128i ib = _mm_load_si128((const __m128i *)(s->cb + 4 * b));
        __m256d rx = _mm256_sub_pd(_mm256_i32gather_pd(s->mx, ib, 8), _mm256_i32gather_pd(s->mx, ia, 8));
        __m256d ry = _mm256_sub_pd(_mm256_i32gather_pd(s->my, ib, 8), _mm256_i32gather_pd(s->my, ia, 8));
        _mm256_store_pd(rxs + 4 * b, rx);
        _mm256_store_pd(rys + 4 * b, ry);
        if (s->need_torsion) {                                      /* eq. (14) */
            __m256d d = _mm256_sub_pd(vatan2(ry, rx), _mm256_load_pd(s->th0 + 4 * b));
            d = vsel(_mm256_cmp_pd(d, V(M_PI), _CMP_GE_OQ), _mm256_sub_pd(d, V(2.0 * M_PI)), d);
            d = vsel(_mm256_cmp_pd(d, V(-M_PI), _CMP_LT_OQ), _mm256_add_pd(d, V(2.0 * M_PI)), d);
            _mm256_store_pd(dth + 4 * b, d);
            sum = _mm256_add_pd(sum, d);
        }
    }
    __m256d mean = _mm256_div_pd(vhsum(sum), V(nc > 0 ? nc : 1));   /* eq. (15) */
    for (int b = 0; b < nb; b++) {
        int o = 4 * b;
        __m256d rx = _mm256_load_pd(rxs + o), ry = _mm256_load_pd(rys + o);
        __m256d half_a = _mm256_mul_pd(V(0.5), _mm256_load_pd(s->stiff + o));
        __m256d l = _mm256_sqrt_pd(_mm256_add_pd(_mm256_mul_pd(rx, rx), _mm256_mul_pd(ry, ry)));
        __m256d dl = _mm256_sub_pd(l, _mm256_load_pd(s->l0 + o));            /* eq. (10) */
        _mm256_store_pd(s->energy[0] + o, _mm256_mul_pd(half_a, _mm256_mul_pd(dl, dl)));  /* (12) */
        __m256d ex = _mm256_sub_pd(rx, _mm256_load_pd(s->rdx0 + o));         /* eq. (18) */
        __m256d ey = _mm256_sub_pd(ry, _mm256_load_pd(s->rdy0 + o));
        _mm256_store_pd(s->energy[2] + o, _mm256_mul_pd(half_a, _mm256_add_pd(     /* (20) */
            _mm256_mul_pd(ex, ex), _mm256_mul_pd(ey, ey))));
        /* eq. (11): direction r / l, or the rest direction when both ends coincide */
        __m256d pos = _mm256_cmp_pd(l, V(0.0), _CMP_GT_OQ);
        __m256d inv_l = _mm256_div_pd(V(1.0), vsel(pos, l, V(1.0)));
        __m256d cx = vsel(pos, _mm256_mul_pd(rx, inv_l), _mm256_load_pd(s->c0 + o));
        __m256d cy = vsel(pos, _mm256_mul_pd(ry, inv_l), _mm256_load_pd(s->s0 + o));
        __m256d g = _mm256_mul_pd(_mm256_load_pd(s->a_euc + o), dl);
        __m256d ux = _mm256_mul_pd(g, cx), uy = _mm256_mul_pd(g, cy);
        if (s->need_torsion) {
            __m256d d = _mm256_sub_pd(_mm256_load_pd(dth + o), mean);        /* eq. (15) */
            _mm256_store_pd(s->energy[1] + o, _mm256_mul_pd(half_a, _mm256_mul_pd(d, d)));  /* (17) */
            __m256d sn, cs;                                                    /* eq. (16) */
            vsincos(_mm256_mul_pd(_mm256_load_pd(s->a_tor + o), d), &sn, &cs);
            __m256d cm1 = _mm256_sub_pd(cs, V(1.0));
            ux = _mm256_add_pd(ux, _mm256_sub_pd(_mm256_mul_pd(rx, cm1), _mm256_mul_pd(ry, sn)));
            uy = _mm256_add_pd(uy, _mm256_add_pd(_mm256_mul_pd(ry, cm1), _mm256_mul_pd(rx, sn)));
        } else {
            _mm256_store_pd(s->energy[1] + o, V(0.0));
        }
        __m256d a_car = _mm256_load_pd(s->a_car + o);                          /* eq. (19) */
        ux = _mm256_add_pd(ux, _mm256_mul_pd(a_car, ex));
        uy = _mm256_add_pd(uy, _mm256_mul_pd(a_car, ey));
        __m128i ia = _mm_load_si128((const __m128i *)(s->ca + o));
        __m128i ib = _mm_load_si128((const __m128i *)(s->cb + o));
        __m256d wa = _mm256_i32gather_pd(s->inv_mass, ia, 8), wb = _mm256_i32gather_pd(s->inv_mass, ib, 8);
        _mm256_store_pd(uax + o, _mm256_mul_pd(ux, wa));
        _mm256_store_pd(uay + o, _mm256_mul_pd(uy, wa));
        _mm256_store_pd(ubx + o, _mm256_mul_pd(ux, wb));
        _mm256_store_pd(uby + o, _mm256_mul_pd(uy, wb));
    }
    for (int k = 0; k < nc; k++) {                                   /* scatter */
        int i = s->ca[k], j = s->cb[k];
        ddx[i] += uax[k];
        ddy[i] += uay[k];
        ddx[j] -= ubx[k];
        ddy[j] -= uby[k];
    }
    for (int i = 0; i < s->n; i += 4) {
        _mm256_store_pd(s->mx + i, _mm256_add_pd(_mm256_load_pd(s->mx + i), _mm256_loadu_pd(ddx + i)));
        _mm256_store_pd(s->my + i, _mm256_add_pd(_mm256_load_pd(s->my + i), _mm256_loadu_pd(ddy + i)));
    }
}


#define PEER_LOOP
#include "peer.h"
