"""The TELEMETRY and ENERGIES payloads of the host link (docs/protocol.md): the tracker
states quantised to a few bytes each, the optional velocity block and instance-state
trailer, and the per-connection energies.  springtrack.wire frames them; both ends (the
firmware, hostctl) import these codecs through it.
"""
from __future__ import annotations

import math
import struct

import numpy as np

from ..track import STATE_NAMES, TRACK_DTYPE, TRACKING_CODE   # decoded TELEMETRY: track records
from .errors import WireError

MAX_PAYLOAD = 1024        # bytes: the longest payload a frame of springtrack.wire carries


# ---- TELEMETRY ------------------------------------------------------------------------
# Header: u64 t_us, u16 generation (low 16 bits), f32 mean energy, u8 tracker count;
# then 8 bytes per tracker (see docs/protocol.md):
#   x, y  u16  position in 1/16 px (0 .. 2047.9375, clamped); x bit 15 = active,
#              y bit 15 = sensitive
#   sx, sy u8  standard deviation sqrt(sxx), sqrt(syy) in 1/4 px (0 .. 63.75, saturated)
#   rho   i8   correlation sxy / (sx sy) * 127
#   act   u8   activity, log-scaled: round(16 log2(1 + A)), A = 2^(code/16) - 1
TELE_HDR = struct.Struct("<QHfB")
TELE_TRACKER = np.dtype([("x", "<u2"), ("y", "<u2"), ("sx", "u1"), ("sy", "u1"),
                         ("rho", "i1"), ("act", "u1")])
POS_SCALE = 16.0
POS_MAX = 0x7FFF / POS_SCALE
SIGMA_SCALE = 4.0
RHO_SCALE = 127
ACT_SCALE = 16.0
NUMERIC_FIELDS = ("x", "y", "sxx", "sxy", "syy", "activity")
FLOAT32_MAX = float(np.finfo(np.float32).max)


def float32_code(value: float) -> float:
    """A value as float32 can carry it: NaN stays NaN, magnitudes beyond float32's range
    become +-inf (struct would raise OverflowError instead)."""
    v = float(value)
    if math.isfinite(v) and abs(v) > FLOAT32_MAX:
        return math.copysign(math.inf, v)
    return v


def quantise_trackers(trackers) -> np.ndarray:
    """TELE_TRACKER records of tracker states given as fields x, y, sxx, sxy, syy,
    activity, active, sensitive (a structured array or a dict of arrays, any numeric dtypes,
    any shape: one snapshot or a block of them).  A non-finite value raises WireError: it
    has no code, and sending it as a clamped number would be a lie (the firmware drops such
    snapshots and counts them before they get here).

    The quantisation of docs/protocol.md from the float state; the integer-only kernel packs
    the same layout from its fixed-point state (fixed/csrc/fixed_telemetry.c: its scales are
    checked against these at import, its codes within one of these in
    tests/test_springtrack/fixed/test_fixed_telemetry.py)."""
    tr = trackers
    bad = [k for k in NUMERIC_FIELDS if not np.all(np.isfinite(np.asarray(tr[k], float)))]
    if bad:
        raise WireError(f"TELEMETRY: non-finite tracker state ({', '.join(bad)}) has no code")
    with np.errstate(invalid="ignore"):
        x = np.clip(tr["x"], 0.0, POS_MAX)
        y = np.clip(tr["y"], 0.0, POS_MAX)
        sx = np.sqrt(np.maximum(tr["sxx"].astype(float), 0.0))
        sy = np.sqrt(np.maximum(tr["syy"].astype(float), 0.0))
        den = sx * sy
        rho = np.where(den > 0, tr["sxy"].astype(float) / np.where(den > 0, den, 1), 0.0)
        act = np.maximum(tr["activity"].astype(float), 0.0)
    rec = np.empty(np.shape(tr["x"]), TELE_TRACKER)
    rec["x"] = np.rint(x * POS_SCALE).astype(np.uint16) | (np.asarray(tr["active"], bool).astype(np.uint16) << 15)
    rec["y"] = np.rint(y * POS_SCALE).astype(np.uint16) | (np.asarray(tr["sensitive"], bool).astype(np.uint16) << 15)
    rec["sx"] = np.minimum(np.rint(sx * SIGMA_SCALE), 255)
    rec["sy"] = np.minimum(np.rint(sy * SIGMA_SCALE), 255)
    rec["rho"] = np.rint(np.clip(rho, -1.0, 1.0) * RHO_SCALE)
    rec["act"] = np.minimum(np.rint(ACT_SCALE * np.log2(1.0 + act)), 255)
    return rec


# Velocities (optional, after the records): u8 VELOCITY_TAG, then per tracker i16 vx, i16 vy
#   in VEL_UNIT px/s (+-262,136 px/s, saturated; the kernels hold |v| to 250,000 px/s,
#   springtrack.reference.VELOCITY_MAX).  Sent only when a velocity is not 0 (the motion
#   model on, eq. M7); absent, every tracker is still.  The tag, 0, is never the first
#   byte of a states trailer (its run count is at least 1).
TELE_VELOCITY = np.dtype([("vx", "<i2"), ("vy", "<i2")])
VEL_UNIT = 8.0
VELOCITY_TAG = 0


def quantise_velocities(trackers) -> np.ndarray:
    """TELE_VELOCITY records of the velocities ``vx``, ``vy`` (px/s) of tracker states (a
    structured array or a dict of arrays); a non-finite one raises WireError (no code)."""
    v = [np.asarray(trackers[k], float) for k in ("vx", "vy")]
    if not all(np.all(np.isfinite(a)) for a in v):
        raise WireError("TELEMETRY: non-finite tracker velocity has no code")
    rec = np.empty(np.shape(v[0]), TELE_VELOCITY)
    for k, a in zip(("vx", "vy"), v):
        rec[k] = np.clip(np.rint(a / VEL_UNIT), -0x7FFF, 0x7FFF)
    return rec


# Trailer (optional): the model instances' states, as runs over the trackers in order:
#   u8 runs, then runs x (u8 state, u16 trackers); the states are springtrack.instances'
#   codes (0 searching, 1 tracking, 2 lost).  Absent: every tracker's instance tracking.
TELE_RUN = struct.Struct("<BH")


def state_runs(states) -> list:
    """[(state, count), ...] of a per-tracker state array, in order."""
    st = np.asarray(states, np.uint8).ravel()
    if not len(st):
        return []
    cut = np.flatnonzero(np.diff(st)) + 1
    starts = np.concatenate([[0], cut])
    ends = np.concatenate([cut, [len(st)]])
    return [(int(st[a]), int(b - a)) for a, b in zip(starts, ends)]


def encode_telemetry(t_us: int, generation: int, mean_energy: float, records,
                     states=None, velocities=None) -> bytes:
    """Pack one snapshot from its tracker records in the TELE_TRACKER layout (bytes, or an
    array from :func:`quantise_trackers`), the trackers' ``velocities`` (TELE_VELOCITY
    records from :func:`quantise_velocities`; the block is sent only when one is not 0)
    and their instance ``states`` (per tracker; the trailer is sent only when one is not
    tracking).  A mean energy beyond float32's range encodes as +-inf
    (:func:`float32_code`), NaN as NaN."""
    if isinstance(records, np.ndarray):
        records = records.tobytes()
    n, rest = divmod(len(records), TELE_TRACKER.itemsize)
    trailer = b""
    if velocities is not None and np.any(velocities["vx"] | velocities["vy"]):
        if len(velocities) != n:
            raise WireError(f"TELEMETRY: {len(velocities)} velocities for {n} trackers")
        trailer = bytes([VELOCITY_TAG]) + np.ascontiguousarray(velocities, TELE_VELOCITY).tobytes()
    if states is not None and np.any(np.asarray(states) != TRACKING_CODE):
        runs = state_runs(states)
        trailer += bytes([len(runs)]) + b"".join(TELE_RUN.pack(st, c) for st, c in runs)
    if rest or n > 255 or TELE_HDR.size + len(records) + len(trailer) > MAX_PAYLOAD:
        raise WireError(f"TELEMETRY: {len(records)} bytes of tracker records (and "
                        f"{len(trailer)} of velocities and states) are not whole "
                        f"{TELE_TRACKER.itemsize}-byte records that fit one frame of "
                        f"{MAX_PAYLOAD} bytes")
    me = float32_code(mean_energy)
    return (TELE_HDR.pack(int(t_us) & (2**64 - 1), int(generation) & 0xFFFF, me, n)
            + bytes(records) + trailer)


def decode_telemetry(payload: bytes) -> tuple[int, int, float, np.ndarray]:
    """-> (t_us, generation & 0xFFFF, mean_energy, array of TRACK_DTYPE)."""
    if len(payload) < TELE_HDR.size:
        raise WireError(f"TELEMETRY: payload of {len(payload)} bytes is shorter than its header")
    t_us, gen, me, n = TELE_HDR.unpack_from(payload)
    want = TELE_HDR.size + n * TELE_TRACKER.itemsize
    if len(payload) < want:
        raise WireError(f"TELEMETRY: {n} trackers need {want} bytes, payload has {len(payload)}")
    rec = np.frombuffer(payload, TELE_TRACKER, n, TELE_HDR.size)
    out = np.empty(n, TRACK_DTYPE)
    out["x"] = (rec["x"] & 0x7FFF) / POS_SCALE
    out["y"] = (rec["y"] & 0x7FFF) / POS_SCALE
    out["active"] = rec["x"] >> 15
    out["sensitive"] = rec["y"] >> 15
    sx = rec["sx"] / SIGMA_SCALE
    sy = rec["sy"] / SIGMA_SCALE
    out["sxx"] = sx * sx
    out["syy"] = sy * sy
    out["sxy"] = rec["rho"] / RHO_SCALE * sx * sy
    out["activity"] = np.exp2(rec["act"] / ACT_SCALE) - 1.0
    rest = payload[want:]
    if rest[:1] == bytes([VELOCITY_TAG]):
        end = 1 + n * TELE_VELOCITY.itemsize
        if len(rest) < end:
            raise WireError(f"TELEMETRY: a velocity block for {n} trackers needs {end} bytes, "
                            f"has {len(rest)}")
        vel = np.frombuffer(rest, TELE_VELOCITY, n, 1)
        out["vx"] = vel["vx"] * VEL_UNIT
        out["vy"] = vel["vy"] * VEL_UNIT
        rest = rest[end:]
    else:
        out["vx"] = out["vy"] = 0.0                # no velocity block: every tracker still
    out["state"] = _decode_states(rest, n)
    return t_us, gen, me, out


def _decode_states(trailer: bytes, n: int) -> np.ndarray:
    """The per-tracker states of a TELEMETRY trailer (all tracking when there is none)."""
    if not trailer:
        return np.full(n, TRACKING_CODE, np.uint8)
    k = trailer[0]
    if len(trailer) != 1 + k * TELE_RUN.size:
        raise WireError(f"TELEMETRY: a states trailer of {k} runs needs {1 + k * TELE_RUN.size} "
                        f"bytes, has {len(trailer)}")
    runs = [TELE_RUN.unpack_from(trailer, 1 + i * TELE_RUN.size) for i in range(k)]
    if sum(c for _, c in runs) != n or any(st >= len(STATE_NAMES) for st, _ in runs):
        raise WireError(f"TELEMETRY: states trailer {runs} does not cover the {n} trackers "
                        f"with known states")
    return np.repeat(np.array([st for st, _ in runs], np.uint8), [c for _, c in runs])




# ---- ENERGIES (lower rate) --------------------------------------------------------------
# u64 t_us, u8 energy kind (0 euclidean, 1 torsional, 2 cartesian: eqs. 12, 17, 20),
# u16 connection count n, n x float32 energy of each connection; sent at most once per
# ENERGY_PERIOD_US of event time
ENERGY_HDR = struct.Struct("<QBH")
ENERGY_PERIOD_US = 100_000


def encode_energies(t_us: int, kind: int, energies) -> bytes:
    """Energies beyond float32's range encode as +-inf, NaN as NaN."""
    with np.errstate(over="ignore", invalid="ignore"):
        e = np.asarray(energies, dtype=np.float64).astype("<f4")
    if ENERGY_HDR.size + 4 * len(e) > MAX_PAYLOAD:
        raise WireError(f"ENERGIES: {len(e)} connections do not fit one frame")
    return ENERGY_HDR.pack(int(t_us) & (2**64 - 1), int(kind), len(e)) + e.tobytes()


def decode_energies(payload: bytes) -> tuple[int, int, np.ndarray]:
    if len(payload) < ENERGY_HDR.size:
        raise WireError(f"ENERGIES: payload of {len(payload)} bytes is shorter than its header")
    t_us, kind, n = ENERGY_HDR.unpack_from(payload)
    if len(payload) != ENERGY_HDR.size + 4 * n:
        raise WireError(f"ENERGIES: {n} connections need {ENERGY_HDR.size + 4 * n} bytes, "
                        f"payload has {len(payload)}")
    return t_us, kind, np.frombuffer(payload, "<f4", n, ENERGY_HDR.size).astype(np.float64)
