# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
"""The event loop with sampling shared by every tracker backend (see backends/stepper.pxd)."""
cimport numpy as cnp
from libc.stdint cimport int64_t, int32_t, uint32_t, uint16_t, uint8_t, INT64_MAX, INT64_MIN
from libc.string cimport memcpy

from springtrack.events cimport Event
from springtrack.events import EVENT_DTYPE, T_MAX, T_MIN
from springtrack.sampling import HOLD, MAX_PERIOD, UNSET
from springtrack.backends.samples cimport SampleOut, bind_buffers, sample_buffers, take_samples

cnp.import_array()

assert ST_UNSET == UNSET and ST_HOLD == HOLD, "csrc/sampling.h disagrees with springtrack/sampling.py"


cdef Py_ssize_t run_events(const Stepper* sp, const Event* ev, Py_ssize_t n, int64_t sample_us,
                           int64_t* next_t, SampleOut* o) noexcept nogil:
    """Process events until done or the sample buffer is full; returns events consumed.
    The sampling rule (csrc/sampling.h): ``next_t`` ST_UNSET becomes the first sample time
    after ev[0]; before an event at t for which st_sample_due(t, next_t, the last event
    time), one snapshot per sample time <= t (the state after all earlier events), those
    of an empty stretch past its ST_HOLD periods skipped (st_next_sample)."""
    cdef Py_ssize_t k = 0
    cdef int64_t t
    if sample_us <= 0:
        while k < n:
            k += sp.steps(sp.state, ev + k, n - k, INT64_MAX)
            if k < n:                  # stopped at t == INT64_MAX: not a sample time
                sp.step(sp.state, ev[k].t, ev[k].x, ev[k].y)
                k += 1
        return n
    if n > 0 and next_t[0] == ST_UNSET:
        next_t[0] = st_first_sample(ev[0].t, sample_us)
    while True:
        k += sp.steps(sp.state, ev + k, n - k, next_t[0])
        if k >= n:
            return n
        t = ev[k].t                    # st_sample_due(t, next_t[0], the last event time)
        while True:
            next_t[0] = st_next_sample(t, next_t[0], sp.last_t[0], sample_us)
            if t < next_t[0]:
                break
            if o.count >= o.cap:
                return k
            sp.snapshot(sp.state, next_t[0], o)
            next_t[0] += sample_us


cdef enum:
    LAYOUT_BLOCK = 256      # events converted per block (4 KiB of records: stays in L1)

# Where an event array's fields lie, for any common layout (packed or aligned; t int64,
# uint64, int32 or uint32; x, y any little-endian integer of 2 to 8 bytes, p any of 1 to 8
# bytes or bool): byte offsets, the bytes of t and whether it is signed.  x, y and p are
# read from their low bytes, as numpy's cast to EVENT_DTYPE does (uint16, uint8).
cdef struct Layout:
    Py_ssize_t stride, ot, ox, oy, op
    int tsize
    bint tsigned


def layout_of(events):
    """(stride, t offset, x offset, y offset, p offset, t bytes, t signed) of a 1-D
    structured array the kernels' loop reads as it is, or None (then it is converted:
    ``springtrack.events.as_events``)."""
    if not isinstance(events, cnp.ndarray) or events.ndim != 1 or events.dtype.names is None:
        return None
    f = events.dtype.fields
    try:
        t, x, y, p = (f[k] for k in ("t", "x", "y", "p"))
    except KeyError:
        return None
    for (dt, _), kinds, sizes in ((t, "iu", (4, 8)), (x, "iu", (2, 4, 8)), (y, "iu", (2, 4, 8)),
                                  (p, "iub", (1, 2, 4, 8))):
        if dt.kind not in kinds or dt.itemsize not in sizes or dt.byteorder == ">" \
                or dt.subdtype is not None:
            return None
    return (events.strides[0], t[1], x[1], y[1], p[1], t[0].itemsize, t[0].kind == "i")


cdef inline Layout packed_layout() noexcept nogil:
    """The packed record of expelliarmus, tonic and numpy files (t int64, x, y int16, p
    uint8: 13 bytes): passed to the inline readers below as constants, the compiler
    specialises them for it."""
    cdef Layout L
    L.stride, L.ot, L.ox, L.oy, L.op, L.tsize, L.tsigned = 13, 0, 8, 10, 12, 8, True
    return L


cdef inline bint is_packed(const Layout* L) noexcept nogil:
    return (L.stride == 13 and L.ot == 0 and L.ox == 8 and L.oy == 10 and L.op == 12
            and L.tsize == 8)


cdef inline bint records_ok(const char* q, Py_ssize_t n, Layout L, int64_t t_lo,
                           int64_t t_hi, uint16_t xy_sign, uint8_t p_max) noexcept nogil:
    """Every record's t within [t_lo, t_hi], x and y without the bit xy_sign, p <= p_max:
    one pass keeping the extremes (no branch per record), compared at the end."""
    cdef Py_ssize_t i, stride = L.stride, ot = L.ot, ox = L.ox, oy = L.oy, op = L.op
    cdef int64_t t, lo = INT64_MAX, hi = INT64_MIN
    cdef uint16_t x, y, xy = 0
    cdef uint8_t p, pm = 0
    for i in range(n):
        memcpy(&t, q + ot, 8)
        memcpy(&x, q + ox, 2)
        memcpy(&y, q + oy, 2)
        p = (<const uint8_t*>q)[op]
        lo = t if t < lo else lo
        hi = t if t > hi else hi
        xy |= x | y
        pm = p if p > pm else pm
        q += stride
    return n == 0 or (lo >= t_lo and hi <= t_hi and (xy & xy_sign) == 0 and pm <= p_max)


def in_range(events):
    """Whether every event of ``events`` holds values within springtrack.events.RANGES,
    found in one pass over the records, for the layouts with an 8-byte t, 2-byte x and y
    and a 1-byte p (the packed and the aligned records): True, or False (some event is out
    of range: springtrack.events.check names the first); None for any other layout (then
    springtrack.events.check checks it field by field)."""
    if not isinstance(events, cnp.ndarray) or events.ndim != 1 or events.dtype.names is None:
        return None
    lay = layout_of(events)
    if lay is None:
        return None
    f = events.dtype.fields
    dt, dx, dy, dp = (f[k][0] for k in ("t", "x", "y", "p"))
    if dt.itemsize != 8 or dx.itemsize != 2 or dy.itemsize != 2 or dp.itemsize != 1 \
            or dx.kind != dy.kind:
        return None
    cdef Layout L
    L.stride, L.ot, L.ox, L.oy, L.op, L.tsize, L.tsigned = lay
    # uint64 t read as int64: a value past T_MAX reads either above T_MAX or below 0
    cdef int64_t t_lo = T_MIN if dt.kind == "i" else 0, t_hi = T_MAX
    cdef uint16_t xy_sign = 0x8000 if dx.kind == "i" else 0
    cdef uint8_t p_max = 255 if dp.kind == "b" else 1     # a bool is 0 or 1 by its type
    cdef const char* q = <const char*>cnp.PyArray_DATA(events)
    cdef Py_ssize_t n = events.shape[0]
    cdef bint ok
    with nogil:
        if is_packed(&L):
            ok = records_ok(q, n, packed_layout(), t_lo, t_hi, xy_sign, p_max)
        else:
            ok = records_ok(q, n, L, t_lo, t_hi, xy_sign, p_max)
    return bool(ok)


cdef inline void convert_block(const char* q, Layout L, Event* out, Py_ssize_t m) noexcept nogil:
    """Records q[0], q[stride], ... (m of them) as Event structs (little-endian host)."""
    cdef Py_ssize_t i
    cdef int64_t t
    cdef int32_t t32
    cdef uint32_t u32
    cdef uint16_t x, y
    for i in range(m):
        if L.tsize == 8:
            memcpy(&t, q + L.ot, 8)
        elif L.tsigned:
            memcpy(&t32, q + L.ot, 4)
            t = t32
        else:
            memcpy(&u32, q + L.ot, 4)
            t = u32
        memcpy(&x, q + L.ox, 2)
        memcpy(&y, q + L.oy, 2)
        out[i].t = t
        out[i].x = x
        out[i].y = y
        out[i].p = (<const uint8_t*>q)[L.op]
        q += L.stride


cdef Py_ssize_t run_layout(const Stepper* sp, const char* base, const Layout* L, Py_ssize_t n,
                           int64_t sample_us, int64_t* next_t, SampleOut* o) noexcept nogil:
    """run_events over n records of any layout: converted LAYOUT_BLOCK at a time into a
    buffer on the stack (no allocation, stays in L1), each block tracked before the next is
    read.  Returns the events consumed (fewer than n if the sample buffer filled)."""
    cdef Event buf[LAYOUT_BLOCK]
    cdef Py_ssize_t done = 0, m, c
    cdef bint packed = is_packed(L)
    while done < n:
        m = n - done if n - done < LAYOUT_BLOCK else LAYOUT_BLOCK
        if packed:
            convert_block(base + done * L.stride, packed_layout(), buf, m)
        else:
            convert_block(base + done * L.stride, L[0], buf, m)
        c = run_events(sp, buf, m, sample_us, next_t, o)
        done += c
        if c < m:
            break
    return done


cdef tuple run_array(Stepper sp, events, int64_t sample_us, int64_t next_t, Py_ssize_t cap,
                     bint records=False, dict into=None):
    """``Kernel.run`` / ``FixedKernel.run``: (consumed, next_t, samples) where samples is a
    dict of arrays with at most ``cap`` rows (None if sample_us <= 0; keys as
    _samples.sample_buffers; ``next_t`` springtrack.sampling.UNSET before the first event
    sets the first sample time); with ``records`` a kernel that packs TELEMETRY records
    (the Stepper's wire_records) adds them (``wire``).  ``events``: EVENT_DTYPE, read in
    place, or any layout :func:`layout_of` accepts (packed records, other integer types,
    a strided view), converted block by block inside the loop.  ``into``: buffers to
    write the rows in (keys and layout as sample_buffers, no ``wire``; at most ``cap``
    of their rows are used), returned as views; else buffers of ``cap`` rows are made,
    and returned as compact copies when less than half full (a few rows do not hold a
    whole buffer)."""
    cdef cnp.ndarray ev = events
    cdef Py_ssize_t n = ev.shape[0], consumed
    cdef SampleOut o
    cdef Layout L
    cdef bint direct = ev.dtype == EVENT_DTYPE and ev.flags.c_contiguous
    if sample_us >= MAX_PERIOD:
        raise ValueError(f"sampling period {sample_us} us is not below {MAX_PERIOD} us")
    if not direct:
        lay = layout_of(ev)
        if lay is None:
            raise TypeError(f"events must be a 1-D structured array with integer fields t, x, "
                            f"y, p (springtrack.events.as_events converts others), got "
                            f"{ev.dtype}")
        L.stride, L.ot, L.ox, L.oy, L.op, L.tsize, L.tsigned = lay
    if sample_us <= 0:
        cap = 0
    if into is None or sample_us <= 0:
        out = sample_buffers(cap, sp.n, &o, records and sp.wire_records)
    else:
        out = bind_buffers(into, sp.n, &o)
        if cap < o.cap:
            o.cap = cap
    cdef const Event* p = <const Event*>cnp.PyArray_DATA(ev)
    cdef const char* base = <const char*>cnp.PyArray_DATA(ev)
    with nogil:
        if direct:
            consumed = run_events(&sp, p, n, sample_us, &next_t, &o)
        else:
            consumed = run_layout(&sp, base, &L, n, sample_us, &next_t, &o)
    if sample_us <= 0:
        return consumed, next_t, None
    return consumed, next_t, take_samples(out, &o, into is None and 2 * o.count < o.cap)
