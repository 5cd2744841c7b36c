"""Q formats of the fixed-point kernel: conversions from float parameters/models, done
once at load time and handed to the integer-only C step (springtrack/fixed/csrc/fixed_step.c)
as two streams of 32-bit words (:func:`model_words`, :func:`params_words`, read by
``fx_load_model`` and ``fx_set_params``), and the constant lookup tables, written into
``springtrack/fixed/csrc/fixed_tables.h`` by :func:`tables_header` (``python -m
springtrack.fixed.q`` regenerates it; a test checks it is current).
docs/fixed_point.md gives the ranges and error bounds.

Every conversion rounds to nearest and raises ``ValueError`` naming the quantity when
the value does not fit its format, instead of wrapping silently.
"""
from __future__ import annotations

import math
import struct
import sys
from pathlib import Path

import numpy as np

from .. import limits as _limits
from ..gate import covariance_gain

POS_FRAC = 32                 # positions Q.32 px (int64)
POS_LIM_PX = float(_limits.POS_LIMIT_PX)   # |position| < 8192 px (state saturates there)
COV_FRAC = 40                 # covariances Q.40 px^2
D2_FRAC = 27                  # Mahalanobis d^2 and the gate, Q.27 (uint32, < 32)
KTAU_FRAC = 40                # log2(e) / tau per us, Q.40
GAIN_FRAC = 30                # stiffness, a1, energy_gain: Q2.30, <= 1
MASS_FRAC = 24                # 1 / mass, Q7.24
ACT_FRAC = 32                 # activity Q.32
ENERGY_FRAC = 40              # energies Q.40
EXP2_BITS = 10                # exp2 table of 2^10 + 1 entries
CORDIC_N = 30
ATAN_BITS = 10                # atan table of 2^10 + 2 entries
PARAMS_HEAD = 24              # fx_set_params: words before the two decay tables
SIM_FRAC = 28                 # fx_move: the similarity's a, b, Q.28 (|.| < 8)
SIM_T_LIM_PX = float(1 << 20)  # and its translation, Q.32, |.| < 2^20 px
# the motion model (eqs. M1-M9, fixed/csrc/fixed_motion.c): velocities Q.32 px/us, the
# horizon Q.8 us, c_h and the Kalman gain's bound Q.30, its threshold Q.32
VEL_FRAC = 32
VEL_UNIT = 1e6 / (1 << VEL_FRAC)   # a Q.32 px/us velocity in px/s
LEAD_FRAC = 8
KALMAN_FRAC = 32
MOTION_WORDS = 10             # fx_set_params: the motion model's words, after the tables
# the smallest alpha_position the Kalman covariance's Q.32 holds with the motion model on:
# its position variance settles near 4 / alpha1^2 event spreads^2 (< 2^22 here)
MOTION_ALPHA_MIN = 1e-3
LOG2E = 1.0 / math.log(2.0)


def q(value: float, frac: int, name: str, lo: float | None = None, hi: float | None = None) -> int:
    """round(value * 2^frac), checked against [lo, hi] (in real units)."""
    if not math.isfinite(value):
        raise ValueError(f"fixed kernel: {name} must be finite, got {value!r}")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise ValueError(f"fixed kernel: {name}={value!r} is outside the range [{lo}, {hi}] "
                         f"of its Q format (docs/fixed_point.md)")
    return int(round(value * (1 << frac)))


def gain(value: float, name: str) -> int:
    """A gain in [0, 1] as Q2.30 (stiffness)."""
    return q(value, GAIN_FRAC, name, 0.0, 1.0)


def gain_pair(g: float, a: float, names: str) -> tuple[int, int, int]:
    """Two gains in [0, 1] as 32-bit mantissas over a shared 2^sh, sh in [31, 62], the
    larger in [2^30, 2^31): the covariance gain and a2 of eq. (4), whose ratio sets the
    covariance's fixed point, keep 30-31 significant bits each even for a2 = 5e-5."""
    q(g, 0, names, 0.0, 1.0)                          # range checks
    q(a, 0, names, 0.0, 1.0)
    big = max(g, a)
    sh = 62 if big <= 0 else max(31, min(62, 30 - math.floor(math.log2(big))))
    while sh > 31 and max(round(g * 2.0 ** sh), round(a * 2.0 ** sh)) >= 1 << 31:
        sh -= 1
    gm, am = int(round(g * 2.0 ** sh)), int(round(a * 2.0 ** sh))
    return min(gm, (1 << 31) - 1), min(am, (1 << 31) - 1), sh


def mantissa(value: float, name: str) -> tuple[int, int]:
    """A value in [0, 2^7) as a mantissa m < 2^31 and a shift sh in [24, 62], value ~ m
    2^-sh, with the largest such m (31 significant bits; values below 2^-32 keep fewer)."""
    q(value, 0, name, 0.0, 128.0)
    sh = 62 if value <= 0 else max(24, min(62, 30 - math.floor(math.log2(value))))
    while sh > 24 and round(value * 2.0 ** sh) >= 1 << 31:
        sh -= 1
    return int(round(value * 2.0 ** sh)), sh


def exp2_table() -> list[int]:
    """2^(-k / 1024) for k = 0..1024, Q.30."""
    n = 1 << EXP2_BITS
    return [int(round(2.0 ** (-k / n) * (1 << 30))) for k in range(n + 1)]


def atan_table() -> list[int]:
    """atan(2^-i) as binary angles (2^32 = 2 pi), i = 0..CORDIC_N-1."""
    return [int(round(math.atan(2.0 ** -i) / (2 * math.pi) * 2 ** 32)) for i in range(CORDIC_N)]


def atan_unit_table() -> list[int]:
    """atan(k / 1024) as binary angles, k = 0..1025 (the last entry pads interpolation at 1)."""
    n = 1 << ATAN_BITS
    return [int(round(math.atan(min(k, n) / n) / (2 * math.pi) * 2 ** 32)) for k in range(n + 2)]


def hyp_tables() -> tuple[list[int], list[int]]:
    """sqrt(1 + t^2) and 1 / sqrt(1 + t^2) at t = k / 1024, k = 0..1025, Q.30 (polar form)."""
    n = 1 << ATAN_BITS
    ts = [min(k, n) / n for k in range(n + 2)]
    return ([int(round(math.sqrt(1 + t * t) * (1 << 30))) for t in ts],
            [int(round((1 << 30) / math.sqrt(1 + t * t))) for t in ts])


DECAY_BITS = 9               # activity decay: two tables of 2^9 entries (dt < 2^18 us)


def decay_tables(tau_us: float) -> tuple[list[int], list[int]]:
    """exp(-j / tau) and exp(-512 j / tau) for j = 0..511, Q.30 (rounded): the activity
    decay of eq. (6) for dt = 512 dt_hi + dt_lo < 2^18 us is the product of two entries."""
    n = 1 << DECAY_BITS
    lo = [int(round(math.exp(-j / tau_us) * (1 << 30))) for j in range(n)]
    hi = [int(round(math.exp(-j * n / tau_us) * (1 << 30))) for j in range(n)]
    return lo, hi


GAUSS_N = 1024               # exp(-d2 / 2): tables at d2 steps of 2^-5 (d2 < 32) and 2^-15


def gauss_tables() -> tuple[list[int], list[int]]:
    """exp(-j 2^-5 / 2) and exp(-j 2^-15 / 2) for j = 0..1023, Q.30 (rounded): the kernel
    value of eq. (2) is their product for d2 = hi 2^-5 + lo 2^-15 + r, times 1 - r / 2."""
    return ([int(round(math.exp(-j * 2.0 ** -6) * (1 << 30))) for j in range(GAUSS_N)],
            [int(round(math.exp(-j * 2.0 ** -16) * (1 << 30))) for j in range(GAUSS_N)])


def sqrt_table() -> list[int]:
    """floor(sqrt(j 2^54) / 2) for j = 256..1024: the integer sqrt's seed (Q.-1 so that the
    last entry, 2^31, fits uint32)."""
    import math as _m
    return [_m.isqrt(j << 54) // 2 for j in range(256, 1025)]


def cordic_x0() -> int:
    """1 / prod(sqrt(1 + 2^-2i)), Q.60: the start vector that makes CORDIC's gain 1."""
    k = 1.0
    for i in range(CORDIC_N):
        k *= math.sqrt(1.0 + 2.0 ** (-2 * i))
    return int(round((1.0 / k) * 2 ** 60))


def angle(rad: float) -> int:
    """Radians as a binary angle in [0, 2^32)."""
    return int(round(rad / (2 * math.pi) * 2 ** 32)) % (1 << 32)


def params_q(p, nc: int) -> dict:
    """The kernel's integer parameters for springtrack.params.Params ``p``, within the
    limits every backend shares (springtrack.limits.check_params, as Params checks)."""
    _limits.check_params(p)
    gate = p.gate_d2
    tau = p.activity_tau_us
    k_tau = int(round(LOG2E / tau * 2 ** KTAU_FRAC))
    never = p.energy_scale >= max(nc, 1)             # e <= total = nc mean: never over
    gm, am, sh = gain_pair(covariance_gain(p), p.alpha_covariance,
                           "alpha_covariance / its gain")
    return dict(
        a1=gain(p.alpha_position, "alpha_position"),
        cov_gm=gm, cov_am=am, cov_sh=sh,
        energy_gain=gain(p.energy_gain, "energy_gain"),
        gate=q(gate, D2_FRAC, "gate_d2", 0.0, 31.0),
        k_tau=min(k_tau, (1 << 32) - 1),           # used only while dt_max > 2^18 us: < 2^27
        dt_max=-(-(32 << KTAU_FRAC) // k_tau),     # 2^-32 and beyond: decay = 0 in Q.30
        act_thr=q(min(p.activity_threshold, 2.0 ** 29), ACT_FRAC, "activity_threshold"),
        escale_never=1 if never else 0,
        escale=mantissa(0.0 if never else p.energy_scale, "energy_scale"),   # < nc <= 128
        # squares as products, rounded exactly (x ** 2 is libm's pow, not always): the
        # microcontroller image computes the same words (docs/mcu.md, "PARAM_SET by name")
        smin2=q(p.sigma_min_px * p.sigma_min_px, COV_FRAC, "sigma_min_px^2"),
        smax2=q(p.sigma_max_px * p.sigma_max_px, COV_FRAC, "sigma_max_px^2"),
        decay=decay_tables(tau),
        period=p.spring_period,
        ekind=p.energy_kind_index,
        tau_bits=struct.unpack("<II", struct.pack("<d", float(tau))),
        pull_sim=1 if p.pull_similarity else 0,
        car_sim=1 if p.cartesian_similarity else 0,
        motion=motion_q(p),
    )


def motion_q(p) -> list[int]:
    """The motion model's words (eqs. M1-M9, reference.py; fixed/csrc/fixed_motion.c):
    ceil(tau_m) us, 1 / tau_m as a mantissa and its shift, the horizon H Q.8 us, c_h Q.30,
    the Kalman gain's bound max(alpha1, 1e-6) Q.30 and the position variance above which it
    binds, alpha1 / (1 - alpha1) Q.32, and |h|'s bound sigma_max Q.32 px."""
    tau = float(p.motion_tau_us)
    if 0.0 < tau < 1.0:
        raise _limits.LimitError(
            f"motion_tau_us={tau!r}: the integer kernel's motion model needs tau_m >= 1 us "
            f"(event times are whole us) or 0 (off)")
    a1 = max(float(p.alpha_position), 1e-6)              # reference: 1 / inv_a1
    if tau > 0.0 and a1 < MOTION_ALPHA_MIN:
        raise _limits.LimitError(
            f"alpha_position={p.alpha_position!r} with motion_tau_us={tau!r}: the integer "
            f"kernel's Kalman filter holds alpha_position >= {MOTION_ALPHA_MIN} (its position "
            f"variance settles near 4 / alpha_position^2); raise it, or track with --backend "
            f"cython")
    inv, inv_sh = mantissa(1.0 / tau, "1 / motion_tau_us") if tau > 0.0 else (0, 31)
    thr = (1 << 63) - 1 if a1 >= 1.0 else min(
        (1 << 63) - 1, q(a1 / (1.0 - a1), KALMAN_FRAC, "alpha_position / (1 - alpha_position)"))
    return [math.ceil(tau), inv, inv_sh,
            q(p.prediction_horizon_us, LEAD_FRAC, "prediction_horizon_us", 0.0, 2.0 ** 23 - 1),
            q(p.polarity_gain, GAIN_FRAC, "polarity_gain", 0.0, 1.0),
            q(a1, GAIN_FRAC, "alpha_position", 0.0, 1.0), *_w64(thr),
            *_w64(q(p.sigma_max_px, POS_FRAC, "sigma_max_px", 0.0, 64.0))]


def _w64(v: int) -> list[int]:
    """An int64 as two 32-bit words, low first (fixed_step.c's word64)."""
    v &= (1 << 64) - 1
    return [v & 0xFFFFFFFF, v >> 32]


def _int32_words(words: list[int]) -> np.ndarray:
    return np.array([w & 0xFFFFFFFF for w in words], np.uint32).view(np.int32)


def params_words(p, nc: int) -> np.ndarray:
    """The word stream fx_set_params reads (fixed/csrc/fixed_step.c; FX_PARAMS_WORDS words)."""
    pq = params_q(p, nc)
    lo, hi = pq["decay"]
    words = [pq["a1"], pq["cov_gm"], pq["cov_am"], pq["cov_sh"], pq["energy_gain"], pq["gate"],
             pq["k_tau"], *_w64(pq["dt_max"]), *_w64(pq["act_thr"]), *pq["escale"],
             pq["escale_never"], *_w64(pq["smin2"]), *_w64(pq["smax2"]), pq["period"],
             pq["ekind"], *pq["tau_bits"], pq["pull_sim"], pq["car_sim"], *lo, *hi,
             *pq["motion"]]
    assert len(words) == PARAMS_HEAD + 2 * (1 << DECAY_BITS) + MOTION_WORDS
    return _int32_words(words)


def model_words(arr: dict, width: int, height: int) -> np.ndarray:
    """The word stream fx_load_model reads, from ShapeModel.arrays() (checked by model_q)."""
    mq = model_q(arr, width, height)
    n, nc = len(mq["mx"]), len(mq["stiff"])
    box = _limits.position_box(width, height)       # the state guard's, whole px
    words = [n, nc, width, height, *box]
    for i in range(n):
        words += [*_w64(mq["mx"][i]), *_w64(mq["my"][i]), *_w64(mq["sxx"][i]),
                  *_w64(mq["sxy"][i]), *_w64(mq["syy"][i]), mq["mq"][i], mq["invm"][i],
                  *_w64(mq["gdx0"][i]), *_w64(mq["gdy0"][i])]
    for k in range(nc):
        words += [int(arr["ca"][k]), int(arr["cb"][k]), int(arr["kinds"][k]), mq["stiff"][k],
                  *_w64(mq["l0"][k]), *_w64(mq["dx0"][k]), *_w64(mq["dy0"][k]), mq["th0"][k],
                  mq["c0x"][k], mq["c0y"][k]]
    return _int32_words(words)


def move_words(sim, model, n: int, nc: int) -> np.ndarray:
    """The word stream fx_move reads (fixed/csrc/fixed_step.c): the similarity ``sim`` = (a, b,
    tx, ty), x -> A x + t with A = [[a, -b], [b, a]] (a, b Q.28; tx, ty Q.32), then the
    words of ``model``, the instance's model moved by it; ``n``, ``nc``: the loaded
    instance's trackers and connections, which the model must have."""
    if len(model.trackers) != n or len(model.connections) != nc:
        raise ValueError(f"move: the model has {len(model.trackers)} trackers and "
                         f"{len(model.connections)} connections, the kernel {n} and {nc}")
    a, b, tx, ty = (float(v) for v in sim)
    lim = float(1 << (31 - SIM_FRAC)) - 2.0 ** -SIM_FRAC
    head = [q(a, SIM_FRAC, "similarity a", -lim, lim), q(b, SIM_FRAC, "similarity b", -lim, lim),
            *_w64(q(tx, POS_FRAC, "similarity tx", -SIM_T_LIM_PX, SIM_T_LIM_PX)),
            *_w64(q(ty, POS_FRAC, "similarity ty", -SIM_T_LIM_PX, SIM_T_LIM_PX))]
    return np.concatenate([_int32_words(head),
                           model_words(model.arrays(), model.width, model.height)])


RELOCATE_COV_LIM = float(1 << (52 - COV_FRAC))   # fx_relocate's covariances, px^2


def relocate_words(idx, x, y, sxx, sxy, syy) -> np.ndarray:
    """The word stream fx_relocate reads (fixed/csrc/fixed_move.c): the count, then per
    tracker its index within the instance, its mean (Q.32) and covariance (Q.40)."""
    lim = POS_LIM_PX
    words = [len(idx)]
    for k, j in enumerate(idx):
        where = f"relocate tracker {int(j)}"
        words += [int(j), *_w64(q(float(x[k]), POS_FRAC, f"{where} x", -lim, lim - 1.0)),
                  *_w64(q(float(y[k]), POS_FRAC, f"{where} y", -lim, lim - 1.0)),
                  *_w64(q(float(sxx[k]), COV_FRAC, f"{where} sxx", 0.0, RELOCATE_COV_LIM)),
                  *_w64(q(float(sxy[k]), COV_FRAC, f"{where} sxy", -RELOCATE_COV_LIM,
                          RELOCATE_COV_LIM)),
                  *_w64(q(float(syy[k]), COV_FRAC, f"{where} syy", 0.0, RELOCATE_COV_LIM))]
    return _int32_words(words)


def model_q(arr: dict, width: int, height: int) -> dict:
    """The kernel's integer model (positions, springs, masses) from ShapeModel.arrays(),
    within the limits every backend shares (springtrack.limits.check_model, as ShapeModel
    checks): so every conversion below fits its format."""
    _limits.check_model(width, height, arr)
    lim = POS_LIM_PX
    pos = lambda v, name: q(float(v), POS_FRAC, name, -lim, lim - 1.0)  # noqa: E731
    mass = [float(m) for m in arr["mass"]]
    mmax = max(mass)
    out = dict(
        mx=[pos(v, f"trackers[{i}].x") for i, v in enumerate(arr["x"])],
        my=[pos(v, f"trackers[{i}].y") for i, v in enumerate(arr["y"])],
        sxx=[q(float(v), COV_FRAC, f"trackers[{i}].sxx") for i, v in enumerate(arr["sxx"])],
        sxy=[q(float(v), COV_FRAC, f"trackers[{i}].sxy") for i, v in enumerate(arr["sxy"])],
        syy=[q(float(v), COV_FRAC, f"trackers[{i}].syy") for i, v in enumerate(arr["syy"])],
        mq=[max(1, int(round(m / mmax * (1 << 24)))) for m in mass],
        invm=[q(1.0 / m, MASS_FRAC, f"trackers[{i}] 1/mass") for i, m in enumerate(mass)],
        gdx0=[pos(v, f"trackers[{i}] x - G") for i, v in enumerate(arr["gdx0"])],
        gdy0=[pos(v, f"trackers[{i}] y - G") for i, v in enumerate(arr["gdy0"])],
        stiff=[], l0=[], dx0=[], dy0=[], th0=[], c0x=[], c0y=[],
    )
    for k in range(len(arr["ca"])):
        a = float(arr["stiffness"][k])
        where = f"connections[{k}]"
        out["stiff"].append(gain(a, f"{where}.stiffness"))
        out["l0"].append(q(float(arr["l0"][k]), POS_FRAC, f"{where} rest length", 0.0, 2 * 1.5 * lim))
        out["dx0"].append(q(float(arr["dx0"][k]), POS_FRAC, f"{where} rest dx", -2 * lim, 2 * lim))
        out["dy0"].append(q(float(arr["dy0"][k]), POS_FRAC, f"{where} rest dy", -2 * lim, 2 * lim))
        th = float(arr["th0"][k])
        out["th0"].append(angle(th))
        out["c0x"].append(int(round(math.cos(th) * (1 << 30))))
        out["c0y"].append(int(round(math.sin(th) * (1 << 30))))
    return out


TABLES_H = Path(__file__).resolve().parent / "csrc" / "fixed_tables.h"


def _c_array(ctype: str, name: str, values: list[int], comment: str) -> str:
    rows = [", ".join(f"{v}u" for v in values[i:i + 8]) for i in range(0, len(values), 8)]
    body = ",\n    ".join(rows)
    return f"/* {comment} */\nstatic const {ctype} {name}[{len(values)}] = {{\n    {body}}};\n"


def tables_header() -> str:
    """The text of fixed/csrc/fixed_tables.h: the kernel's constant tables (flash on a
    microcontroller), generated from the functions above."""
    hyp, ihyp = hyp_tables()
    ghi, glo = gauss_tables()
    parts = [
        "/* Constant tables of the fixed-point kernel (fixed/csrc/fixed_step.c), generated by\n"
        "   springtrack/fixed/q.py (python -m springtrack.fixed.q): do not edit.  They are\n"
        "   `static const`, so a microcontroller build keeps them in flash. */\n"
        "#ifndef SPRINGTRACK_FIXED_TABLES_H\n#define SPRINGTRACK_FIXED_TABLES_H\n\n"
        "#include <stdint.h>\n",
        _c_array("uint32_t", "FX_EXP2_LUT", exp2_table(), "2^(-k / 1024), Q.30, k = 0..1024"),
        _c_array("uint32_t", "FX_ATAN_LUT", atan_table(), "atan(2^-i), binary angle (CORDIC)"),
        _c_array("uint32_t", "FX_ATAN_TAB", atan_unit_table(), "atan(k / 1024), binary angle"),
        _c_array("uint32_t", "FX_HYP_TAB", hyp, "sqrt(1 + (k / 1024)^2), Q.30"),
        _c_array("uint32_t", "FX_IHYP_TAB", ihyp, "1 / sqrt(1 + (k / 1024)^2), Q.30"),
        _c_array("uint32_t", "FX_SQRT_TAB", sqrt_table(), "floor(sqrt((j + 256) 2^54) / 2)"),
        _c_array("uint32_t", "FX_GAUSS_HI", ghi, "exp(-j 2^-5 / 2), Q.30 (d2 < 32)"),
        _c_array("uint32_t", "FX_GAUSS_LO", glo, "exp(-j 2^-15 / 2), Q.30"),
        f"/* 1 / CORDIC gain, Q.60 */\n#define FX_CORDIC_X0 ((int64_t){cordic_x0()})\n",
        "#endif\n",
    ]
    return "\n".join(parts)


if __name__ == "__main__":
    TABLES_H.write_text(tables_header())
    print(f"wrote {TABLES_H}", file=sys.stderr)
