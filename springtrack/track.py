"""A tracking result: tracker states sampled at regular event times, and its CSV form.

The track record is defined here once: the per-tracker fields (:data:`TRACK_FIELDS`),
their dtype (:data:`TRACK_DTYPE`) and the CSV header (:data:`CSV_HEADER`), used by the
kernels' sample rows, the firmware, the wire protocol, ``hostctl record`` and the renderer.

CSV schema (``springtrack track``, ``firmware-sim --record``, ``hostctl record``)::

    t_us,tracker,x,y,sxx,sxy,syy,activity,vx,vy,active,sensitive,state

one row per tracker per sample time (springtrack.sampling: every multiple of the period
from the first event on, an empty stretch for its first HOLD periods and at its end only:
at most sampling.PER_EVENT samples per event); ``t_us`` is
event time in microseconds, the row holds the state after all events with t < t_us;
positions in px (the means predicted to t_us along their velocities, eq. M1),
covariances in px^2, velocities ``vx``/``vy`` in px/s (eq. M7; 0 where the motion model
is off), ``active``/``sensitive`` are 0/1; ``state`` is the
state of the tracker's model instance (``searching``, ``tracking`` or ``lost``:
springtrack.instances, docs/acquisition.md).  A CSV without the ``state`` column reads as
``tracking``, one without ``vx``/``vy`` as still.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field, fields

import numpy as np

FLOAT_FIELDS = ("x", "y",                 # position, px (eq. 3)
                "sxx", "sxy", "syy",      # covariance, px^2 (eq. 4)
                "activity",               # A, eq. (6), decayed to the sample time
                "vx", "vy")               # velocity, px/s (eq. M7)
BOOL_FIELDS = ("active",                  # A > activity threshold
               "sensitive")               # takes part in the energy criteria (eq. 21)
CODE_FIELDS = ("state",)                  # the instance's state (instances.InstanceState)
TRACK_FIELDS = FLOAT_FIELDS + BOOL_FIELDS + CODE_FIELDS
# one tracker's state; aligned: the C view is TrackRow in track.pxd (checked at import by
# springtrack.backends.samples, whose sample rows are arrays of it)
TRACK_DTYPE = np.dtype([(f, "<f8") for f in FLOAT_FIELDS] + [(f, "?") for f in BOOL_FIELDS]
                       + [(f, "u1") for f in CODE_FIELDS], align=True)
CSV_HEADER = ("t_us", "tracker") + TRACK_FIELDS
# the header without the velocity (and without the state): read as still (and tracking)
_VELOCITY = ("vx", "vy")
_CSV_NO_VELOCITY = tuple(h for h in CSV_HEADER if h not in _VELOCITY)
_FLAGS_AT = 2 + len(FLOAT_FIELDS)           # CSV column of the first flag
_STATE_AT = _FLAGS_AT + len(BOOL_FIELDS)    # CSV column of the state
# the instance states' names in the CSV, by code (instances.InstanceState)
STATE_NAMES = ("searching", "tracking", "lost", "not found")
TRACKING_CODE = STATE_NAMES.index("tracking")


@dataclass
class Track:
    t_us: np.ndarray                      # (n,) int64
    ids: list                             # K tracker ids
    x: np.ndarray                         # (n, K) float64, px
    y: np.ndarray
    sxx: np.ndarray                       # px^2
    sxy: np.ndarray
    syy: np.ndarray
    activity: np.ndarray
    vx: np.ndarray                        # px/s
    vy: np.ndarray
    active: np.ndarray                    # (n, K) bool
    sensitive: np.ndarray
    state: np.ndarray | None = None       # (n, K) uint8, the instance's state (STATE_NAMES);
    #                                       None: tracking throughout
    energy: np.ndarray | None = None      # (n, 3) mean energy: euclidean, torsional, cartesian
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.state is None:
            self.state = np.full(np.shape(self.x), TRACKING_CODE, np.uint8)

    def __len__(self) -> int:
        return len(self.t_us)

    @classmethod
    def empty(cls, ids) -> "Track":
        k = len(ids)
        z = np.empty((0, k))
        b = np.empty((0, k), bool)
        return cls(np.empty(0, np.int64), list(ids), z, z.copy(), z.copy(), z.copy(), z.copy(),
                   z.copy(), z.copy(), z.copy(), b, b.copy(), np.empty((0, k), np.uint8),
                   np.empty((0, 3)))

    @classmethod
    def concat(cls, parts, ids) -> "Track":
        """One Track of ``parts`` in order.  A lone part is returned as it is (no copy);
        parts that keep their sample rows (:meth:`from_samples`) are joined row by row
        with one copy, the fields views of the joined rows."""
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty(ids)
        en = None
        if all(p.energy is not None for p in parts):
            en = np.concatenate([p.energy for p in parts]) if len(parts) > 1 else parts[0].energy
        t = np.concatenate([p.t_us for p in parts]) if len(parts) > 1 else parts[0].t_us
        rows = [p.rows() for p in parts]
        if all(r is not None for r in rows):
            return cls.of_rows(t, ids, rows[0] if len(rows) == 1 else join_rows(rows), en)
        kw = {f: np.concatenate([getattr(p, f) for p in parts]) if len(parts) > 1
              else getattr(parts[0], f) for f in TRACK_FIELDS}
        return cls(t, list(ids), energy=en, **kw)

    @classmethod
    def from_samples(cls, samples: dict, ids) -> "Track":
        """A Track from a tracker loop's sample rows: ``t`` (rows,), ``trackers`` (rows, K)
        of TRACK_DTYPE, ``energy`` (rows, 3).  The fields are views of the rows (no copy)."""
        return cls.of_rows(samples["t"], ids, samples["trackers"], samples["energy"])

    @classmethod
    def of_rows(cls, t_us, ids, rows: np.ndarray, energy=None) -> "Track":
        """A Track whose fields are views of ``rows`` ((n, K) TRACK_DTYPE), which it keeps."""
        if rows.dtype != TRACK_DTYPE or rows.ndim != 2:
            raise TypeError(f"sample rows must be (rows, trackers) {TRACK_DTYPE}, not "
                            f"{rows.ndim}-d {rows.dtype}")
        track = cls(t_us, list(ids), energy=energy, **{f: rows[f] for f in TRACK_FIELDS})
        track._rows = rows
        return track

    def rows(self) -> np.ndarray | None:
        """The (n, K) TRACK_DTYPE rows the fields are views of, or None (a Track built
        from separate arrays, or one whose field was replaced by another array since)."""
        rows = getattr(self, "_rows", None)
        if rows is None:
            return None
        at = data_address(rows)
        for f in TRACK_FIELDS:
            a = getattr(self, f)
            if not (isinstance(a, np.ndarray) and a.dtype == TRACK_DTYPE[f]
                    and a.shape == rows.shape and a.strides == rows.strides
                    and data_address(a) == at + TRACK_DTYPE.fields[f][1]):
                return None
        return rows

    def between(self, t0_us: int | None, t1_us: int | None) -> "Track":
        """The samples at times in [t0_us, t1_us) (None: unbounded), their fields copies."""
        t = self.t_us
        keep = np.ones(len(t), bool)
        if t0_us is not None:
            keep &= t >= t0_us
        if t1_us is not None:
            keep &= t < t1_us
        kw = {f: getattr(self, f)[keep] for f in TRACK_FIELDS}
        energy = self.energy[keep] if self.energy is not None else None
        return Track(t[keep], list(self.ids), energy=energy, meta=dict(self.meta), **kw)

    def tracker(self, tracker_id) -> dict:
        k = self.ids.index(tracker_id)
        return {f: getattr(self, f)[:, k] for f in TRACK_FIELDS} | {"t_us": self.t_us}

    def to_csv(self, path_or_file) -> None:
        own = isinstance(path_or_file, (str, bytes)) or hasattr(path_or_file, "__fspath__")
        f = open(path_or_file, "w", newline="") if own else path_or_file
        try:
            f.write(",".join(CSV_HEADER) + "\n")
            self.write_rows(f)
        finally:
            if own:
                f.close()

    def write_rows(self, f) -> None:
        """The CSV rows (no header) to the text file ``f``."""
        k = len(self.ids)
        for s in range(0, len(self), 2000):            # format in blocks, not per row
            e = min(s + 2000, len(self))
            t = np.repeat(self.t_us[s:e], k)
            ids = np.tile(np.array(self.ids, dtype=object), e - s)
            cols = [getattr(self, c)[s:e].ravel() for c in FLOAT_FIELDS]
            flags = [getattr(self, c)[s:e].ravel().astype(np.uint8) for c in BOOL_FIELDS]
            states = np.array(STATE_NAMES, dtype=object)[
                np.minimum(self.state[s:e].ravel(), len(STATE_NAMES) - 1)]
            f.writelines(
                f"{a},{b},{c:.6f},{d:.6f},{g:.6f},{h:.6f},{i:.6f},{j:.6g},{u:.3f},{v:.3f},"
                f"{m},{n},{o}\n"
                for a, b, c, d, g, h, i, j, u, v, m, n, o in zip(
                    t.tolist(), ids, *(c.tolist() for c in cols), *(c.tolist() for c in flags),
                    states.tolist()))


def data_address(a: np.ndarray) -> int:
    """Where ``a``'s first element is in memory (views of one buffer compare by it)."""
    return a.__array_interface__["data"][0]


def join_rows(blocks) -> np.ndarray:
    """(n, K) TRACK_DTYPE blocks joined (or one copied) in one copy: as opaque records,
    since numpy copies an aligned record dtype field by field."""
    raw = np.dtype((np.void, TRACK_DTYPE.itemsize))
    return np.concatenate([b.view(raw) for b in blocks]).view(TRACK_DTYPE)


# the dataclass spells the fields out for readers and type checkers: keep it the record
assert tuple(f.name for f in fields(Track))[2:2 + len(TRACK_FIELDS)] == TRACK_FIELDS


def read_csv(path) -> Track:
    """Read a track CSV (any row order); raises ValueError naming the file on bad content."""
    with open(path, newline="") as f:
        reader = csv.reader(f)
        header = next(reader, None)
        header = None if header is None else tuple(h.strip() for h in header)
        known = (CSV_HEADER, CSV_HEADER[:_STATE_AT], _CSV_NO_VELOCITY,
                 _CSV_NO_VELOCITY[:_STATE_AT - len(_VELOCITY)])
        if header not in known:
            raise ValueError(f"{path}: not a track CSV (expected header {','.join(CSV_HEADER)})")
        rows = list(reader)
    if "vx" not in header:                 # still parts: zero velocity columns
        rows = [r[:_FLAGS_AT - len(_VELOCITY)] + ["0", "0"] + r[_FLAGS_AT - len(_VELOCITY):]
                for r in rows]
    with_state = "state" in header
    if not rows:
        raise ValueError(f"{path}: track CSV has a header but no rows")
    try:
        t = np.array([int(r[0]) for r in rows], np.int64)
        names = [r[1] for r in rows]
        vals = np.array([[float(v) for v in r[2:_FLAGS_AT]] for r in rows])
        flags = np.array([[int(v) for v in r[_FLAGS_AT:_STATE_AT]] for r in rows], bool)
        code = {name: k for k, name in enumerate(STATE_NAMES)}
        states = np.array([code[r[_STATE_AT]] if with_state else TRACKING_CODE for r in rows],
                          np.uint8)
    except (ValueError, IndexError, KeyError, OverflowError) as e:   # Overflow: t beyond int64
        raise ValueError(f"{path}: malformed track row: {e}") from None
    ids = list(dict.fromkeys(names))
    times = np.unique(t)
    col = {n: i for i, n in enumerate(ids)}
    ti = np.searchsorted(times, t)
    ci = np.array([col[n] for n in names])
    shape = (len(times), len(ids))
    arrs = {}
    for j, fname in enumerate(FLOAT_FIELDS):
        a = np.full(shape, np.nan)
        a[ti, ci] = vals[:, j]
        arrs[fname] = a
    for j, fname in enumerate(BOOL_FIELDS):
        a = np.zeros(shape, bool)
        a[ti, ci] = flags[:, j]
        arrs[fname] = a
    a = np.full(shape, TRACKING_CODE, np.uint8)
    a[ti, ci] = states
    arrs["state"] = a
    return Track(times, ids, **arrs)
