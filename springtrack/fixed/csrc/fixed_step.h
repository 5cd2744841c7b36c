/* Integer-only tracker step of springtrack (Valeiras et al. 2015, Algorithm 1).
 *
 * This unit is the fixed-point twin of springtrack/kernel/kernel.pyx: the same algorithm and
 * interpretation choices (see springtrack/reference.py), on integers only, written for
 * 32-bit cores: the host's `--backend fixed` and the microcontroller build
 * (springtrack/mcu/) compile this same source.  It compiles with `gcc
 * -mgeneral-regs-only` (no floating-point register) and, for Cortex-M4/M7 and RV32IMAC,
 * links without any floating-point, 128-bit or 64-bit division helper
 * (tests/test_springtrack/fixed/test_fixed_integer_only.py, tests/test_springtrack/mcu/test_mcu.py).  Q formats (docs/fixed_point.md):
 *
 *   positions mx, my, gdx0                int64  Q.32 px accumulators, clamped to +-FX_POS_LIM
 *   covariances sxx, sxy, syy            int64  Q.40 px^2 accumulators (<= 4096 px^2)
 *   inverse covariance ia, ib2, ic        int32  mantissas, per-tracker exponent (ish)
 *   candidate offsets                     int32  Q.32 px >> osh (per tracker: +-8 sigma)
 *   Mahalanobis d^2, gate                 uint32 Q.27 (< 32)
 *   spring geometry r, l, angles ...      int32  Q.16 px (rest-frame u, v: Q.18)
 *   spring vectors, l0, dx0, dy0, dl, e   int64  Q.32 px (the energy criteria's precision)
 *   activity                              int64  Q.32
 *   energies                              int64  Q.40 (px^2, or rad^2 for torsion)
 *   gains a1, energy_gain, stiffness      uint32 Q.30 (<= 1.0)
 *   energy_scale                          uint32 mantissa over 2^escale_sh (< 2^31)
 *   cov_gain, a2                          uint32 mantissas over 2^cov_sh (< 2^31)
 *   1/mass                                uint32 Q7.24
 *   angles                                uint32 binary angle, 2^32 = 2 pi
 *   exp / exp2 / atan / hypot / sqrt      const uint32 tables in flash (fixed_tables.h)
 *   motion model (eqs. M1-M8, fixed_motion.c): velocity vx, vy int32 Q.32 px/us; half
 *   offset hx, hy int64 Q.32 px; Kalman P in units of tau_m (pp, pv tau_m, vv tau_m^2)
 *   int64 Q.32; its gains and dt / tau_m uint32 Q.30; the lead of eq. (M1) Q.8 us
 *
 * 32-bit discipline: every multiplication is a 32 x 32 -> 64-bit product (one
 * SMULL/UMULL/SMLAL on Cortex-M, MUL + MULH on RV32); a 64-bit accumulator times a 32-bit
 * gain is two of them (its high and low word), exactly.  64-bit values are timestamps,
 * counters, the accumulators above and such products.  Divisions are 32-bit (UDIV/DIVU):
 * the few 64 / 32 quotients are built from two of them (fx_udiv64).
 *
 * Arithmetic right shifts of negative values are floor divisions (GCC and Clang define
 * them so); no signed overflow can happen (bounds in docs/fixed_point.md), and the
 * places where a value could leave its range saturate and count.
 */
#ifndef SPRINGTRACK_FIXED_STEP_H
#define SPRINGTRACK_FIXED_STEP_H

#include <stdint.h>

/* capacities: the host builds the largest; a microcontroller build may define less */
#ifndef FX_MAX_TRACKERS
#define FX_MAX_TRACKERS 64
#endif
#ifndef FX_MAX_CONNECTIONS
#define FX_MAX_CONNECTIONS 128
#endif
/* several model instances in one tracker (springtrack.limits: MAX_INSTANCES,
   MAX_SET_TRACKERS, MAX_SET_CONNECTIONS): one fx_state per instance, in an fx_set */
#ifndef FX_MAX_INSTANCES
#define FX_MAX_INSTANCES 16
#endif
#define FX_MAX_SET_TRACKERS 256
#define FX_MAX_SET_CONNECTIONS 512
/* A 64-bit host keeps eq. (14)'s angles at every spring update (fx_state's dth) for its
   samples, which read every energy kind (fx_energies); a 32-bit core, whose telemetry
   reads only the criterion's kind, computes them again when they are read instead of
   storing them at every update.  The same integers either way. */
#define FX_KEEP_ANGLES (UINTPTR_MAX > 0xffffffffu)
/* the motion model's modes (fixed_motion.c in_motion): at rest (the paper's step), half
   offsets without velocities (no prediction), velocities (predictions) */
#define FX_MOTION_REST 0
#define FX_MOTION_EDGES 1
#define FX_MOTION_FULL 2
#define FX_CELL_SHIFT 3                     /* spatial index cells of 8 x 8 px */
#define FX_POS_FRAC 32                      /* positions Q.32 */
#define FX_POS_LIM ((int64_t)8192 << 32)    /* |position| < 8192 px */
#define FX_SPRING_BOX_PX 16                 /* [ref] SPRING_BOX_PX */
#define FX_SPRING_BOX_ALL (1 << 30)         /* [ref] SPRING_BOX_ALL: the box of every event */
#define FX_D2_FRAC 27                       /* Mahalanobis d^2 Q.27 */
#define FX_EXP2_BITS 10                     /* exp2 table: 1024 intervals + 1 */
#define FX_EXP2_N (1 << FX_EXP2_BITS)
#define FX_CORDIC_N 30                      /* CORDIC iterations */
#define FX_ATAN_BITS 10                     /* atan table: 1024 intervals + 2 */
#define FX_SQRT_SHIFT 54                    /* sqrt table: sqrt(j 2^54) / 2, j = 256..1024 */
#define FX_SQRT_J0 256
#define FX_SQRT_N 769
#define FX_INDEX_MARGIN ((int32_t)3 << 16)  /* px added around an indexed gate box ... */
#define FX_INDEX_GROW_SHIFT 3               /* ... after enlarging it by 2^-3 of itself */
#define FX_DECAY_BITS 9                     /* activity decay: two tables of 2^9 entries ... */
#define FX_DECAY_N (1 << FX_DECAY_BITS)     /* ... cover dt < 2^18 us exactly */
#define FX_GAUSS_N 1024                     /* exp(-d2/2): d2 steps of 2^-5 and 2^-15 */

/* the word streams of fx_load_model / fx_set_params (springtrack/fixed/q.py writes them) */
#define FX_MODEL_HEAD 8                     /* n, nc, width, height, the position box */
#define FX_MODEL_TRACKER 16                 /* words per tracker */
#define FX_MODEL_CONNECTION 13              /* words per connection */
#define FX_PARAMS_HEAD 24                   /* words before the two decay tables */
#define FX_PARAMS_MOTION 10                 /* the motion model's words, after the tables */
#define FX_PARAMS_WORDS (FX_PARAMS_HEAD + 2 * FX_DECAY_N + FX_PARAMS_MOTION)
#define FX_MOVE_HEAD 6                      /* fx_move: the similarity's words, then a model's */
#define FX_SIM_FRAC 28                      /* the similarity's a, b: Q.28 (|.| < 8) */
#define FX_SIM_T_LIM ((int64_t)1 << 52)     /* its translation: Q.32, |.| < 2^20 px */
#define FX_RELOCATE_TRACKER 11              /* fx_relocate: index, x, y, sxx, sxy, syy */
#define FX_RELOCATE_COV_LIM ((int64_t)1 << 52)  /* its covariances: Q.40, < 2^12 px^2 */

enum { FX_NO_TRACKER = -1, FX_BACK_IN_TIME = -2, FX_OUT_OF_SENSOR = -3 };
/* fx_load_model / fx_set_params / fx_move results (FX_ERR_MODEL: fx_move's model is not the
   loaded one moved: other trackers, connections, masses, stiffnesses or sensor) */
enum { FX_OK = 0, FX_ERR_WORDS = -1, FX_ERR_CAPACITY = -2, FX_ERR_CELLS = -3, FX_ERR_RANGE = -4,
       FX_ERR_MODEL = -5 };

typedef struct {
    /* geometry and model size */
    int32_t n, nc, width, height;
    /* parameters, converted by springtrack/fixed/q.py */
    uint32_t a1, energy_gain;                 /* Q.30, <= 2^30 = 1.0 */
    uint32_t cov_gm, cov_am;                  /* cov_gain, a2 = these / 2^cov_sh, < 2^31 */
    int32_t cov_sh;                           /* 31 .. 62 */
    uint32_t gate;                            /* d^2 gate, Q.27 (< 32) */
    uint32_t k_tau;                           /* log2(e) / tau per us, Q.40 (used when < 2^27) */
    int64_t dt_max;                           /* us after which the decay is taken as 0 */
    int64_t act_thr;                          /* Q.32 */
    uint32_t escale;                          /* energy_scale = escale 2^-escale_sh, < 2^31 */
    int32_t escale_sh;                        /* 24 .. 62 */
    int32_t escale_never;                     /* 1: energy_scale >= nc, nothing is ever over */
    int64_t smin2, smax2;                     /* Q.40 px^2 */
    int32_t period, ekind, need_torsion;
    int32_t pull_sim, car_sim;                /* eq. (22) / eqs. (18)-(20) in the similarity frame */
    uint32_t tau_bits[2];                     /* activity_tau_us's float64 bits: its identity */
    /* the motion model (eqs. M1-M8, fixed_motion.c; 0: off): tau_m as ceil(tau_m) us and
       1 / tau_m = inv_tau 2^-inv_tau_sh (inv_tau < 2^31); the horizon H, Q.8 us; c_h, Q.30;
       |h| <= h_max (sigma_max, Q.32 px); the Kalman gain's bound alpha1, Q.30, which binds
       while pp > kcap_thr (alpha1 / (1 - alpha1), Q.32) */
    int32_t tau_ceil, inv_tau_sh, horizon8;
    int32_t moving;                           /* in_motion() when the parameters were set:
                                                 FX_MOTION_REST, _EDGES or _FULL */
    uint32_t inv_tau, c_h, kcap;
    int64_t h_max, kcap_thr;
    int32_t has_params;
    /* derived by fx_prepare() from the model and parameters above */
    int32_t used_kinds;                       /* bit q: a spring or the criterion is of kind q */
    int32_t unit_mass;                        /* every 1/mass is exactly 1 (no division) */
    int32_t equal_mass;                       /* every centre-of-mass weight is the same */
    int64_t decay_span;                       /* min(dt_max, 2^(2 FX_DECAY_BITS)) us */
    /* the model's means and covariances (the state starts from them and the guard resets
       it to them), and the position box (springtrack.limits.position_box, whole px): after
       a spring update every mean has lo <= its integer part < hi, or the guard resets the
       state (fx_reset) */
    int64_t rest_x[FX_MAX_TRACKERS], rest_y[FX_MAX_TRACKERS];
    int64_t rest_sxx[FX_MAX_TRACKERS], rest_sxy[FX_MAX_TRACKERS], rest_syy[FX_MAX_TRACKERS];
    int32_t pos_lo_x, pos_hi_x, pos_lo_y, pos_hi_y;
    /* tracker state, structure of arrays */
    int64_t mx[FX_MAX_TRACKERS], my[FX_MAX_TRACKERS];
    int64_t sxx[FX_MAX_TRACKERS], sxy[FX_MAX_TRACKERS], syy[FX_MAX_TRACKERS];
    /* the inverse covariance for eq. (2): ia = ia_m 2^-f etc., refreshed after each update;
       osh: candidate offsets are (Q.32 offset) >> osh, d2 = (quadratic form) >> dsh */
    int32_t ia[FX_MAX_TRACKERS], ib2[FX_MAX_TRACKERS], ic[FX_MAX_TRACKERS];
    uint8_t osh[FX_MAX_TRACKERS], dsh[FX_MAX_TRACKERS];
    int64_t act[FX_MAX_TRACKERS];
    int64_t tlast[FX_MAX_TRACKERS];           /* the tracker's last event (eq. 6, t_k of M1) */
    /* the motion model per tracker (eqs. M1-M8): velocity Q.32 px/us (|.| <= 2^30), half
       offset between the ON and OFF edges Q.32 px, the time t_m its mean refers to (us),
       the Kalman covariance in units of tau_m: pp, pv tau_m, vv tau_m^2, Q.32 */
    int32_t vx[FX_MAX_TRACKERS], vy[FX_MAX_TRACKERS];
    int64_t hx[FX_MAX_TRACKERS], hy[FX_MAX_TRACKERS];
    int64_t tm[FX_MAX_TRACKERS];
    int64_t kpp[FX_MAX_TRACKERS], kpv[FX_MAX_TRACKERS], kvv[FX_MAX_TRACKERS];
    uint32_t mq[FX_MAX_TRACKERS];             /* mass / max mass, Q.24 (centre of mass) */
    uint32_t invm[FX_MAX_TRACKERS];           /* 1 / mass, Q7.24 */
    int64_t gdx0[FX_MAX_TRACKERS], gdy0[FX_MAX_TRACKERS];
    uint64_t isolated;                        /* bit i: tracker i has no connection */
    uint64_t sensitive_mask;
    /* connections */
    int32_t ca[FX_MAX_CONNECTIONS], cb[FX_MAX_CONNECTIONS], kinds[FX_MAX_CONNECTIONS];
    uint64_t ends[FX_MAX_CONNECTIONS];        /* bits ca[k] and cb[k] */
    uint32_t stiff[FX_MAX_CONNECTIONS];       /* Q2.30 */
    int64_t l0[FX_MAX_CONNECTIONS], dx0[FX_MAX_CONNECTIONS], dy0[FX_MAX_CONNECTIONS];   /* Q.32 */
    uint32_t th0[FX_MAX_CONNECTIONS];         /* binary angle */
    int32_t c0x[FX_MAX_CONNECTIONS], c0y[FX_MAX_CONNECTIONS];    /* cos, sin th0, Q.30 */
    int64_t energy[3][FX_MAX_CONNECTIONS];   /* read them through fx_energies() */
    int64_t mean_energy;
    /* the similarity frame of the last fit (fit_frame): s R = [[frame_c, -frame_s],
       [frame_s, frame_c]] Q.28 and frame_g, the image of the rest centre of mass (Q.32);
       car_c, car_s: the frame the Cartesian springs of the last update used (the one
       fitted before it), in force for its energies if car_turned */
    int32_t frame_c, frame_s, car_c, car_s, car_turned;
    int64_t frame_gx, frame_gy;
    /* the spring vectors r = x_j - x_i of the last spring update (Q.32 px, |.| < 2^46): the
       energies of the kinds the criterion does not use are computed from them only when
       they are read (fx_energies) */
    int64_t grx[FX_MAX_CONNECTIONS], gry[FX_MAX_CONNECTIONS];
    int32_t energy_stale;                     /* bit q < 3: energy[q] not yet computed;
                                                 bit 3: no torsion energies at that update */
    /* spatial index (see kernel/kernel.pyx): bit i of cells[cy * gw + cx] set if tracker i's
       indexed box covers the cell; bx_* is that box, Q.16 px */
    uint64_t *cells;
    int32_t gw, gh;
    int32_t box_x0[FX_MAX_TRACKERS], box_x1[FX_MAX_TRACKERS];
    int32_t box_y0[FX_MAX_TRACKERS], box_y1[FX_MAX_TRACKERS];
    int32_t bx_lo[FX_MAX_TRACKERS], bx_hi[FX_MAX_TRACKERS];
    int32_t by_lo[FX_MAX_TRACKERS], by_hi[FX_MAX_TRACKERS];
    /* the per-update index check (box_kept): the box's centre (Q.16), the slack left
       there for the mean to move (Q.16), and the variances up to which it holds (Q.40) */
    int32_t bcx[FX_MAX_TRACKERS], bcy[FX_MAX_TRACKERS];
    int32_t devx[FX_MAX_TRACKERS], devy[FX_MAX_TRACKERS];
    int64_t sxx_lim[FX_MAX_TRACKERS], syy_lim[FX_MAX_TRACKERS];
    /* activity decay tables of the current tau (parameters), Q.30 */
    uint32_t decay_lo[FX_DECAY_N];            /* exp(-j / tau), j = 0..511 (us) */
    uint32_t decay_hi[FX_DECAY_N];            /* exp(-512 j / tau) */
    /* counters */
    int64_t last_t, n_valid, n_assigned, n_back, n_outside, n_spring_updates, n_reindex;
    int64_t sat_position, sat_activity, sat_energy, sat_inverse;
    int64_t n_resets;                         /* states the guard reset to the model */
    int32_t since_spring;
#if FX_KEEP_ANGLES
    /* eq. (14)'s angles from rest of the spring vectors grx, gry (binary angle) and their
       mean (eq. 15), kept by the update when its springs use them: fx_energies' torsional
       energies without the geometry again */
    int64_t mean_dth;
    int32_t dth[FX_MAX_CONNECTIONS];
#endif
    /* eq. (M6b) without a velocity: each tracker's ON share of its events, Q.30 (last, so
       that the fields the paper's step uses keep their offsets from the state's start) */
    uint32_t fon[FX_MAX_TRACKERS];
} fx_state;

/* Several model instances (springtrack.instances): one loaded fx_state per instance
   (its trackers, connections, parameters, springs, energies and similarity frame), and
   one event assignment over them: eq. (2)'s argmin over the union of the tracking
   instances' sensitive trackers, ties to the lowest instance, then the lowest index; one
   clock, one count of valid events and one spring period (the shared parameters:
   springtrack.instances.SHARED_PARAMS, equal in every instance); each instance's own
   spring clock (springtrack/reference.py step: the valid events it takes and those no
   tracker takes inside its spring box or inside none), its count
   own[q] + n_free - free0[q]. */
enum { FX_SEARCHING = 0, FX_TRACKING = 1, FX_LOST = 2 };   /* instances.InstanceState */
typedef struct {
    int32_t ni;
    fx_state *inst[FX_MAX_INSTANCES];
    int32_t t0[FX_MAX_INSTANCES];             /* instance q's trackers: t0[q] + [0, n) */
    int32_t state[FX_MAX_INSTANCES];          /* FX_SEARCHING, FX_TRACKING, FX_LOST */
    int64_t last_t, n_valid, n_assigned, n_back, n_outside, n_spring_updates;
    /* the spring clocks: n_free counts the valid events no tracker took outside every
       spring box (one count for every instance); own[q] the events instance q's trackers
       took since its last update and those no tracker took inside its box, free0[q]
       n_free then */
    int64_t n_free;
    int64_t own[FX_MAX_INSTANCES];
    int64_t free0[FX_MAX_INSTANCES];
    /* each instance's spring box ([ref] _spring_box: whole pixels x0, x1, y0, y1): an
       event no tracker takes inside it counts in own[q]; one outside every box in n_free */
    int32_t sbox[FX_MAX_INSTANCES][4];
} fx_set;

/* one event as springtrack.events.EVENT_DTYPE lays it out (16 bytes, springtrack/events.pxd) */
typedef struct {
    int64_t t;
    uint16_t x, y;
    uint8_t p;                                /* polarity: 1 ON, 0 OFF (eq. M4) */
} fx_event;

/* Load a model (the word stream of fixed.q.model_words) into a zeroed-out state that uses
   `cells` (cell_cap entries) as its spatial index; then fx_set_params must follow. */
int fx_load_model(fx_state *s, const int32_t *w, int32_t nw, uint64_t *cells, int32_t cell_cap);
/* Apply parameters (fixed.q.params_words) between two events; a new tau applies from the
   last event on, as in the reference (eq. 6). */
int fx_set_params(fx_state *s, const int32_t *w, int32_t nw);
/* Move the loaded instance rigidly by a similarity x -> A x + t, A = [[a, -b], [b, a]]
   (springtrack.reference.ReferenceTracker.move), between two events: w = a, b (Q.28), tx,
   ty (Q.32, two words each, low first), then the word stream of the model moved by it
   (fixed.q.move_words).  Means mapped, covariances turned and scaled (A S A^T, then
   clamped as eq. (4)'s), the frame's centre mapped; activities, sensitivities,
   deformation, energies and counters kept; the rest geometry from the moved model.  On an
   error nothing changes. */
int fx_move(fx_state *s, const int32_t *w, int32_t nw);
int fx_relocate(fx_state *s, const int32_t *w, int32_t nw);
int32_t fx_cells_needed(int32_t width, int32_t height);

/* one event of polarity p (1 ON, 0 OFF) */
int fx_step(fx_state *s, int64_t t, int32_t x, int32_t y, int32_t p);
/* fx_step over ev[0..n), stopping before the first event with t >= t_stop that is not
   back in time (the sampling rule, sampling.h); returns the events processed (the
   Stepper's steps(), backends/stepper.pxd) */
int64_t fx_steps(fx_state *s, const fx_event *ev, int64_t n, int64_t t_stop);
void fx_springs(fx_state *s);
/* the set: fx_set_init over ni loaded states (each with its parameters), then fx_set_step
   / fx_set_steps as fx_step / fx_steps (the winner's index among all trackers); the
   clock and event counts are copied into every instance */
int fx_set_init(fx_set *g, fx_state *const *inst, int32_t ni);
int fx_set_step(fx_set *g, int64_t t, int32_t x, int32_t y, int32_t p);
int64_t fx_set_steps(fx_set *g, const fx_event *ev, int64_t n, int64_t t_stop);
void fx_set_springs(fx_set *g);
void fx_set_state(fx_set *g, int q, int32_t state);
void fx_energies(fx_state *s);
void fx_prepare(fx_state *s);
void fx_refresh(fx_state *s, int i);
void fx_reindex(fx_state *s, int i);
void fx_clamp_positions(fx_state *s);
/* the tracker state of the model: its means and covariances (clamped), no activity, every
   tracker sensitive, no energy, the identity frame; counters and time kept */
void fx_reset(fx_state *s);
int64_t fx_activity(const fx_state *s, int i, int64_t t);
int fx_check_index(const fx_state *s);
/* building blocks, exported for tests */
int64_t fx_mulsh(int64_t v, uint32_t g, int sh);
uint64_t fx_udiv64(uint64_t n, uint32_t d, uint32_t *rem);
uint32_t fx_divlu32(uint32_t u1, uint32_t u0, uint32_t v, uint32_t *rem);
uint64_t fx_isqrt64(uint64_t v);
uint32_t fx_exp2neg(int64_t w);
int64_t fx_gauss(uint32_t d2);
uint32_t fx_decay(const fx_state *s, int64_t dt);
uint32_t fx_atan2(int64_t y, int64_t x);
void fx_cossin(int64_t angle, int64_t *c, int64_t *sn);
void fx_polar(int32_t x, int32_t y, uint32_t *ang, int32_t *len, int32_t *cx, int32_t *cy);
uint32_t fx_d2(const fx_state *s, int i, int32_t x, int32_t y);
/* eq. (M1): tracker i's mean predicted to event time t (Q.32 px) */
void fx_predicted(const fx_state *s, int i, int64_t t, int64_t *x, int64_t *y);

#endif
