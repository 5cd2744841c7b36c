"""Event Stream 2.x (.es), DVS and ATIS types: streaming decoder and encoder.

Spec: the neuromorphic-paris/event_stream README (docs/formats.md#event-stream-2x).  After
the header (handled by springtrack.io.detect) the payload is a byte state machine; every
event is 5 bytes: a time/flags byte, x (2 bytes LE), y (2 bytes LE).

DVS   OVERFLOW 0xFF: t += 127;  RESET 0xFE: no-op at an event boundary;
      else t += b >> 1, p = b & 1.
ATIS  (b & 0xFC) == 0xFC: t += 63 * (b & 3)  (b == 0xFC is the RESET byte);
      else t += b >> 2, exposure = b & 1, p = (b >> 1) & 1.
Time is a sum of non-negative steps from 0: it cannot wrap or go back, so this format needs
no time base (timebase.pxd).  y is stored as in the file (the format's origin is the
bottom-left corner).  Events with x >= width or y >= height are dropped and counted
('out_of_geometry'); ATIS exposure events are counted and optionally kept apart.
"""
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t
cimport numpy as cnp
import numpy as np

from springtrack.events cimport Event
from springtrack.io.base cimport *
from springtrack.events import as_events

cnp.import_array()

TYPES = {"generic": 0, "dvs": 1, "atis": 2, "color": 4}

cdef enum EsDvsBytes:           # time/flags byte, DVS
    DVS_OVERFLOW = 0xFF         # t += DVS_OVERFLOW_US
    DVS_RESET = 0xFE
    DVS_OVERFLOW_US = 127       # the largest step an event byte holds (7 bits)
    DVS_T_SHIFT = 1             # event byte: t step in bits 7..1, p in bit 0
    DVS_POL_BIT = 0x1

cdef enum EsAtisBytes:          # time/flags byte, ATIS
    ATIS_OVERFLOW_MASK = 0xFC   # (b & MASK) == MASK: t += ATIS_OVERFLOW_US * (b & 3)
    ATIS_RESET = 0xFC
    ATIS_OVERFLOW_COUNT = 0x3
    ATIS_OVERFLOW_US = 63       # the largest step an event byte holds (6 bits)
    ATIS_MAX_OVERFLOW_US = 189  # 0xFF: three overflows
    ATIS_T_SHIFT = 2            # event byte: t step in bits 7..2, p in bit 1, exposure bit 0
    ATIS_POL_BIT = 0x2
    ATIS_EXPOSURE_BIT = 0x1

cdef enum EsEventBytes:         # read state: bytes of the current event seen so far
    ES_AT_BOUNDARY = 0          # next byte: time/flags
    ES_X_LOW = 1
    ES_X_HIGH = 2
    ES_Y_LOW = 3
    ES_Y_HIGH = 4
    ES_EVENT_BYTES = 5
MAX_BYTES = 1 << 31      # refuse to write absurd streams (e.g. absolute epoch timestamps)


cdef class EsDecoder(Decoder):
    cdef bint atis
    cdef int st            # bytes of the current event read so far (EsEventBytes)
    cdef int64_t t
    cdef uint32_t x, y
    cdef uint8_t p, exposure

    def __init__(self, event_type="dvs", int width=0, int height=0, bint keep_exposure=False):
        if event_type not in ("dvs", "atis"):
            raise ValueError(f"es decoder: event type {event_type!r} not supported "
                             "(dvs or atis)")
        self._setup("es", 1, 1, ES_EVENT_BYTES, width, height, keep_exposure)
        self.atis = event_type == "atis"

    @property
    def event_type(self):
        return "atis" if self.atis else "dvs"

    cdef int _pending_state(self) noexcept:
        return self.st

    cdef void _reset_state(self) noexcept:
        self.st = ES_AT_BOUNDARY

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil:
        cdef Py_ssize_t i = 0, k = nout[0], ks = nside[0]
        cdef uint8_t b
        cdef int st = self.st
        cdef int64_t t = self.t
        cdef uint32_t x = self.x, y = self.y
        cdef uint8_t pol = self.p, expo = self.exposure
        cdef uint32_t W = geometry_bound(self.width)
        cdef uint32_t H = geometry_bound(self.height)
        cdef bint atis = self.atis
        while i < n and k < cap:
            b = p[i]
            i += 1
            if st == ES_AT_BOUNDARY:
                if atis:
                    if (b & ATIS_OVERFLOW_MASK) == ATIS_OVERFLOW_MASK:
                        if b & ATIS_OVERFLOW_COUNT:
                            t += ATIS_OVERFLOW_US * (b & ATIS_OVERFLOW_COUNT)
                            self.n.info[<int>IN_OVERFLOW] += 1
                        else:
                            self.n.info[<int>IN_RESET] += 1
                        continue
                    t += b >> ATIS_T_SHIFT
                    expo = b & ATIS_EXPOSURE_BIT
                    pol = (b & ATIS_POL_BIT) != 0
                else:
                    if b == DVS_OVERFLOW:
                        t += DVS_OVERFLOW_US
                        self.n.info[<int>IN_OVERFLOW] += 1
                        continue
                    if b == DVS_RESET:
                        self.n.info[<int>IN_RESET] += 1
                        continue
                    t += b >> DVS_T_SHIFT
                    pol = b & DVS_POL_BIT
                    expo = 0
                st = ES_X_LOW
            elif st == ES_X_LOW:
                x = b
                st = ES_X_HIGH
            elif st == ES_X_HIGH:
                x |= <uint32_t>b << 8
                st = ES_Y_LOW
            elif st == ES_Y_LOW:
                y = b
                st = ES_Y_HIGH
            else:
                y |= <uint32_t>b << 8
                st = ES_AT_BOUNDARY
                if x >= W or y >= H:
                    self.n.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1
                elif expo:
                    self.n.info[<int>IN_EXPOSURE] += 1
                    if side != NULL:
                        side[ks].t = t
                        side[ks].x = <uint16_t>x
                        side[ks].y = <uint16_t>y
                        side[ks].p = pol
                        ks += 1
                else:
                    put_event(&out[k], t, x, y, pol)
                    k += 1
        self.st = st
        self.t = t
        self.x = x
        self.y = y
        self.p = pol
        self.exposure = expo
        self.n.words += i
        nout[0] = k
        nside[0] = ks
        return i


def header(event_type, int width, int height) -> bytes:
    """The 20-byte Event Stream 2.0.0 header for a DVS or ATIS stream."""
    if event_type not in ("dvs", "atis"):
        raise ValueError(f"es header: event type {event_type!r} not supported (dvs or atis)")
    if not (0 < width <= 65535 and 0 < height <= 65535):
        raise ValueError(f"es header: geometry {width}x{height} out of range 1..65535")
    return (b"Event Stream" + bytes([2, 0, 0, TYPES[event_type]])
            + int(width).to_bytes(2, "little") + int(height).to_bytes(2, "little"))


def encode(events, event_type="dvs", exposure=None) -> bytes:
    """Event Stream payload (no header) for time-sorted events, t counted from 0.

    ``exposure`` (ATIS only): optional bool array marking exposure-measurement events.
    Raises ValueError for negative or decreasing timestamps.
    """
    ev = as_events(events)
    cdef Py_ssize_t n = ev.shape[0], i, j = 0, size
    if event_type not in ("dvs", "atis"):
        raise ValueError(f"es encode: event type {event_type!r} not supported (dvs or atis)")
    if n == 0:
        return b""
    t = ev["t"]
    if t[0] < 0 or (n > 1 and np.any(np.diff(t) < 0)):
        raise ValueError("es encode: timestamps must be >= 0 and non-decreasing")
    cdef bint atis = event_type == "atis"
    if exposure is None:
        flags = np.zeros(n, dtype=np.uint8)
    else:
        if not atis:
            raise ValueError("es encode: exposure flags need event_type='atis'")
        flags = np.ascontiguousarray(exposure, dtype=bool).view(np.uint8)
        if flags.shape[0] != n:
            raise ValueError(f"es encode: exposure has {flags.shape[0]} flags for {n} events")
    dt = np.diff(t, prepend=0)
    # DVS: one OVERFLOW byte per 127 us; ATIS: one 0xFF (3 x 63 us) per 189 us plus one
    # 0xFD / 0xFE for the rest.
    if atis:
        extra = dt // ATIS_MAX_OVERFLOW_US + ((dt % ATIS_MAX_OVERFLOW_US) // ATIS_OVERFLOW_US > 0)
    else:
        extra = dt // DVS_OVERFLOW_US
    size = ES_EVENT_BYTES * n + int(extra.sum())
    if size > MAX_BYTES:
        raise ValueError(f"es encode: the stream would take {size:,} bytes, mostly overflow "
                         f"bytes for the time from 0 to {int(t[0]):,} us and the gaps; "
                         "Event Stream time counts from 0: subtract the first timestamp")
    buf = np.empty(size, dtype=np.uint8)
    cdef uint8_t[::1] w = buf
    cdef const uint8_t[::1] fl = flags
    cdef const uint8_t[::1] raw = ev.view(np.uint8)
    cdef const Event* e = <const Event*>&raw[0]
    cdef int64_t prev = 0, d, q
    with nogil:
        for i in range(n):
            d = e[i].t - prev
            prev = e[i].t
            if atis:
                while d >= ATIS_MAX_OVERFLOW_US:
                    w[j] = ATIS_OVERFLOW_MASK | ATIS_OVERFLOW_COUNT
                    j += 1
                    d -= ATIS_MAX_OVERFLOW_US
                if d >= ATIS_OVERFLOW_US:
                    q = d // ATIS_OVERFLOW_US
                    w[j] = <uint8_t>(ATIS_OVERFLOW_MASK | q)
                    j += 1
                    d -= ATIS_OVERFLOW_US * q
                w[j] = <uint8_t>((d << ATIS_T_SHIFT) | (ATIS_POL_BIT if e[i].p else 0)
                                 | (ATIS_EXPOSURE_BIT if fl[i] else 0))
            else:
                while d >= DVS_OVERFLOW_US:
                    w[j] = DVS_OVERFLOW
                    j += 1
                    d -= DVS_OVERFLOW_US
                w[j] = <uint8_t>((d << DVS_T_SHIFT) | (DVS_POL_BIT if e[i].p else 0))
            w[j + ES_X_LOW] = e[i].x & 0xFF
            w[j + ES_X_HIGH] = e[i].x >> 8
            w[j + ES_Y_LOW] = e[i].y & 0xFF
            w[j + ES_Y_HIGH] = e[i].y >> 8
            j += ES_EVENT_BYTES
    return buf.tobytes()
