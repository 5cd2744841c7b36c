"""Event Stream 2.x (.es), DVS and ATIS types: streaming decoder and encoder.

Spec: the neuromorphic-paris/event_stream README (docs/formats.md#event-stream).  After
the header (handled by springtrack.io.detect) the payload is a byte state machine;
every event is 5 bytes: a time/flags byte, x (2 bytes LE), y (2 bytes LE).

DVS   0xFF: overflow, t += 127;  0xFE: reset (no-op at an event boundary);
      else t += b >> 1, p = b & 1.
ATIS  (b & 0xFC) == 0xFC: t += 63 * (b & 3)  (b == 0xFC is the reset byte);
      else t += b >> 2, exposure = b & 1, p = (b >> 1) & 1.
y is stored as in the file (the format's origin is the bottom-left corner).  Events with
x >= width or y >= height are dropped and counted ('out_of_geometry'); ATIS exposure
events are counted and optionally kept apart.
"""
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int64_t, uint64_t
cimport numpy as cnp
import numpy as np

from springtrack.events cimport Event
from springtrack.io.base cimport *
from springtrack.events import as_events

cnp.import_array()

TYPES = {"generic": 0, "dvs": 1, "atis": 2, "color": 4}
MAX_BYTES = 1 << 31      # refuse to write absurd streams (e.g. absolute epoch timestamps)


cdef class EsDecoder(Decoder):
    cdef bint atis
    cdef int st            # bytes of the current event read so far (0 = at a boundary)
    cdef int64_t t
    cdef uint32_t x, y
    cdef uint8_t p, exposure

    def __init__(self, event_type="dvs", int width=0, int height=0, bint keep_exposure=False):
        if event_type not in ("dvs", "atis"):
            raise ValueError(f"es decoder: event type {event_type!r} not supported "
                             "(dvs or atis)")
        self._setup("es", 1, 1, 5, width, height, keep_exposure)
        self.atis = event_type == "atis"

    @property
    def event_type(self):
        return "atis" if self.atis else "dvs"

    cdef int _pending_state(self) noexcept:
        return self.st

    cdef void _reset_state(self) noexcept:
        self.st = 0

    cdef Py_ssize_t _run(self, const uint8_t* p, Py_ssize_t n, Event* out, Py_ssize_t cap,
                         Py_ssize_t* nout, Event* side, Py_ssize_t* nside) noexcept nogil:
        cdef Py_ssize_t i = 0, k = nout[0], ks = nside[0]
        cdef uint8_t b
        cdef int st = self.st
        cdef int64_t t = self.t
        cdef uint32_t x = self.x, y = self.y
        cdef uint8_t pol = self.p, expo = self.exposure
        cdef uint32_t W = self.width if self.width else 0x10000
        cdef uint32_t H = self.height if self.height else 0x10000
        cdef bint atis = self.atis
        while i < n and k < cap:
            b = p[i]
            i += 1
            if st == 0:
                if atis:
                    if (b & 0xFC) == 0xFC:
                        if b & 3:
                            t += 63 * (b & 3)
                            self.info[<int>IN_OVERFLOW] += 1
                        else:
                            self.info[<int>IN_RESET] += 1
                        continue
                    t += b >> 2
                    expo = b & 1
                    pol = (b >> 1) & 1
                else:
                    if b == 0xFF:
                        t += 127
                        self.info[<int>IN_OVERFLOW] += 1
                        continue
                    if b == 0xFE:
                        self.info[<int>IN_RESET] += 1
                        continue
                    t += b >> 1
                    pol = b & 1
                    expo = 0
                st = 1
            elif st == 1:
                x = b
                st = 2
            elif st == 2:
                x |= <uint32_t>b << 8
                st = 3
            elif st == 3:
                y = b
                st = 4
            else:
                y |= <uint32_t>b << 8
                st = 0
                if x >= W or y >= H:
                    self.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1
                elif expo:
                    self.info[<int>IN_EXPOSURE] += 1
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
        self.words += i
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
    # DVS: one 0xFF per 127 us; ATIS: one 0xFF per 189 us plus one 0xFD/0xFE for the rest.
    if atis:
        extra = dt // 189 + ((dt % 189) // 63 > 0)
    else:
        extra = dt // 127
    size = 5 * n + int(extra.sum())
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
                while d >= 189:
                    w[j] = 0xFF
                    j += 1
                    d -= 189
                if d >= 63:
                    q = d // 63
                    w[j] = <uint8_t>(0xFC | q)
                    j += 1
                    d -= 63 * q
                w[j] = <uint8_t>((d << 2) | ((e[i].p != 0) << 1) | (fl[i] != 0))
            else:
                while d >= 127:
                    w[j] = 0xFF
                    j += 1
                    d -= 127
                w[j] = <uint8_t>((d << 1) | (e[i].p != 0))
            w[j + 1] = e[i].x & 0xFF
            w[j + 2] = e[i].x >> 8
            w[j + 3] = e[i].y & 0xFF
            w[j + 4] = e[i].y >> 8
            j += 5
    return buf.tobytes()
