# Prophesee RAW EVT 3.0 words, C level: the decoder's state machine, for Evt3Decoder
# (evt3.pyx) and for loops that decode words themselves.
#
#   from springtrack.io.evt3 cimport Evt3State, evt3_init, evt3_decode_words
#   cdef Evt3State st
#   cdef DecodeCounts n                            # springtrack.io.base: words, anomalies, info
#   evt3_init(&st, width, height)                  # 0: geometry unknown, no check
#   used = evt3_decode_words(&st, &n, words, nw, out, &k, cap)   # up to 12 events per word
#   evt3_lost_data(&st)                            # words were lost: forget the addresses
#
# Word types and fields: evt3_types.h.  The state: the current row (EVT_ADDR_Y), vector
# base and polarity (VECT_BASE_X) and time (EVT_TIME_HIGH through the time base of every
# decoder, timebase.pxd; EVT_TIME_LOW taken as read).
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int32_t, int64_t, uint64_t
from libc.string cimport memcpy

from springtrack.events cimport Event
from springtrack.io.base cimport (Decoder, DecodeCounts, count_time, geometry_bound,
                                  put_event, ANY_COORD, AN_OUT_OF_GEOMETRY, AN_UNKNOWN_TYPE,
                                  AN_ORPHAN, IN_TIME_HIGH, IN_TRIGGERS, IN_OTHERS,
                                  IN_BEFORE_TIME_HIGH, IN_TIME_LOW_BACK)
from springtrack.io.timebase cimport (TimeBase, timebase_init, timebase_known,
                                      timebase_count, timebase_update)

cdef extern from "springtrack/io/evt3_types.h" nogil:
    enum Evt3EventTypes:
        EVT3_EVT_ADDR_Y
        EVT3_EVT_ADDR_X
        EVT3_VECT_BASE_X
        EVT3_VECT_12
        EVT3_VECT_8
        EVT3_EVT_TIME_LOW
        EVT3_CONTINUED_4
        EVT3_EVT_TIME_HIGH
        EVT3_EXT_TRIGGER
        EVT3_OTHERS
        EVT3_CONTINUED_12
    enum:
        EVT3_WORD_BYTES
        EVT3_TIME_LOW_MASK
        EVT3_TH_BITS
        EVT3_TH_SHIFT
        EVT3_VECT_12_BITS
        EVT3_VECT_8_BITS
        EVT3_MAX_EVENTS_PER_WORD
    uint32_t evt3_type(uint16_t v)
    uint32_t evt3_coord(uint16_t v)
    uint32_t evt3_pol(uint16_t v)
    uint32_t evt3_time(uint16_t v)
    uint32_t evt3_vect_mask(uint16_t v, uint32_t bits)
    uint16_t evt3_word(uint32_t type, uint32_t payload)
    uint16_t evt3_addr_x_word(uint32_t pol, uint32_t x)

cdef extern from "springtrack/io/evt3_block.h" nogil:
    ctypedef struct Evt3Run:
        int64_t th
        int64_t t_low_last
        uint64_t tl_back
        int32_t tl
        int32_t y
        int32_t base
        int32_t vp
    size_t evt3_decode_run(const uint8_t* p, size_t nw, Evt3Run* st, uint32_t width,
                           uint32_t height, void* out, size_t* k, size_t cap, size_t* scalar)

cdef extern from *:
    int __builtin_ctz(unsigned int) nogil

cdef struct Evt3State:
    TimeBase tb                # the EVT_TIME_HIGH counter
    int64_t tl                 # last EVT_TIME_LOW value
    int64_t t_low_last         # timestamp set by the last EVT_TIME_LOW word
    int y                      # current row, -1 before the first EVT_ADDR_Y
    int base_x                 # vector base column, -1 before the first VECT_BASE_X
    uint8_t vec_p              # vector polarity
    uint32_t width, height     # coordinates must stay below (geometry_bound)

cdef inline void evt3_init(Evt3State* s, int width, int height) noexcept nogil:
    timebase_init(&s.tb)
    s.tl = 0
    s.t_low_last = 0
    s.y = -1
    s.base_x = -1
    s.vec_p = 0
    s.width = geometry_bound(width)
    s.height = geometry_bound(height)

cdef inline void evt3_lost_data(Evt3State* s) noexcept nogil:
    """Words were lost (a dropped transfer, a reconnect): the row, the vector base and
    the EVT_TIME_LOW bits are stale.  Events need a fresh EVT_ADDR_Y (VECT_BASE_X) again
    (before it they are orphans), and until the next EVT_TIME_LOW the time is the start of
    the time-high period, never ahead of the stream; the time base is kept (the next
    EVT_TIME_HIGH continues it)."""
    s.y = -1
    s.base_x = -1
    s.tl = 0
    s.t_low_last = 0


cdef inline Py_ssize_t evt3_decode_words(Evt3State* s, DecodeCounts* n, const uint8_t* p,
                                         Py_ssize_t nw, Event* out, Py_ssize_t* nout,
                                         Py_ssize_t cap) noexcept nogil:
    """Decode up to nw words at p into out from index nout[0], stopping while out[:cap]
    still has room for a word's worst case (EVT3_MAX_EVENTS_PER_WORD); advance nout[0];
    count in n; return the words consumed."""
    cdef Py_ssize_t k = nout[0], stop = cap - EVT3_MAX_EVENTS_PER_WORD
    cdef const uint8_t* w = p                      # the next word
    cdef const uint8_t* end = p + EVT3_WORD_BYTES * nw
    cdef uint16_t v
    cdef uint32_t typ, x, m
    cdef int b
    cdef uint32_t W = s.width, H = s.height
    cdef Evt3Run r
    cdef size_t done, kk, scalar = 0     # words to decode word by word before the fast path
    # the time in locals for the loop (written back after it): kept in the state, every
    # EVT_TIME_LOW word's load and store of t_low_last would chain through memory.  t is
    # the time base (bits 12 and up) | the last EVT_TIME_LOW (bits 11..0); the time base's
    # counter, touched only by EVT_TIME_HIGH words, stays in the state
    cdef int64_t t = (timebase_count(&s.tb) << EVT3_TH_SHIFT) | s.tl
    cdef int64_t t_low_last = s.t_low_last
    cdef int y = s.y, base = s.base_x
    cdef uint8_t vp = s.vec_p
    # events from out[k0] on have no time base (counted at the first time-high word);
    # k0 = -1 once the time base is known
    cdef Py_ssize_t k0 = -1 if timebase_known(&s.tb) else k
    while w < end and k <= stop:
        # 16 words at a time while they are plain event words (evt3_block.h); the words it
        # leaves go word by word (blocks need the time base)
        if scalar == 0 and k0 < 0:
            r.th = t & ~(<int64_t>EVT3_TIME_LOW_MASK)
            r.tl = <int32_t>(t & EVT3_TIME_LOW_MASK)
            r.t_low_last = t_low_last
            r.tl_back = 0
            r.y = y
            r.base = base
            r.vp = vp
            kk = k
            done = evt3_decode_run(w, (end - w) // EVT3_WORD_BYTES, &r, W, H, out, &kk, cap,
                                   &scalar)
            if done > 0:
                k = kk
                w += done * EVT3_WORD_BYTES
                t = r.th | r.tl
                t_low_last = r.t_low_last
                n.info[<int>IN_TIME_LOW_BACK] += r.tl_back
                y = r.y
                base = r.base
                vp = <uint8_t>r.vp
            if scalar == 0:             # out of words or room: the rest word by word
                scalar = <size_t>(end - w)
            continue
        if scalar > 0:
            scalar -= 1
        memcpy(&v, w, EVT3_WORD_BYTES)   # little-endian host assumed
        w += EVT3_WORD_BYTES
        typ = evt3_type(v)
        if typ == EVT3_EVT_ADDR_X:             # one event
            x = evt3_coord(v)
            if y < 0:
                n.anomalies[<int>AN_ORPHAN] += 1
            elif x >= W or <uint32_t>y >= H:
                n.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1
            else:
                put_event(&out[k], t, x, y, evt3_pol(v))
                k += 1
        elif typ == EVT3_EVT_ADDR_Y:
            y = evt3_coord(v)
        elif typ == EVT3_VECT_12 or typ == EVT3_VECT_8:
            m = evt3_vect_mask(v, EVT3_VECT_12_BITS if typ == EVT3_VECT_12
                               else EVT3_VECT_8_BITS)
            if y < 0 or base < 0:
                n.anomalies[<int>AN_ORPHAN] += 1
                continue
            while m:
                b = __builtin_ctz(m)
                m &= m - 1
                x = <uint32_t>(base + b)
                if x >= W or <uint32_t>y >= H:
                    n.anomalies[<int>AN_OUT_OF_GEOMETRY] += 1
                    continue
                put_event(&out[k], t, x, y, vp)
                k += 1
            base += EVT3_VECT_12_BITS if typ == EVT3_VECT_12 else EVT3_VECT_8_BITS
            if base >= ANY_COORD:
                base = ANY_COORD - 1
        elif typ == EVT3_VECT_BASE_X:
            base = evt3_coord(v)
            vp = evt3_pol(v)
        elif typ == EVT3_EVT_TIME_LOW:
            t = (t & ~EVT3_TIME_LOW_MASK) | evt3_time(v)
            if t < t_low_last:          # real sensors jitter by a few us: kept, counted
                n.info[<int>IN_TIME_LOW_BACK] += 1
            t_low_last = t
        elif typ == EVT3_EVT_TIME_HIGH:
            n.info[<int>IN_TIME_HIGH] += 1
            t = ((timebase_update(&s.tb, evt3_time(v), EVT3_TH_BITS) << EVT3_TH_SHIFT)
                 | (t & EVT3_TIME_LOW_MASK))
            if k0 >= 0:
                n.info[<int>IN_BEFORE_TIME_HIGH] += k - k0
                k0 = -1
        elif typ == EVT3_EXT_TRIGGER:
            n.info[<int>IN_TRIGGERS] += 1
        elif typ == EVT3_CONTINUED_4 or typ == EVT3_OTHERS or typ == EVT3_CONTINUED_12:
            n.info[<int>IN_OTHERS] += 1
        else:
            n.anomalies[<int>AN_UNKNOWN_TYPE] += 1
    count_time(n, &s.tb)
    s.tl = t & EVT3_TIME_LOW_MASK
    s.t_low_last = t_low_last
    if k0 >= 0:
        n.info[<int>IN_BEFORE_TIME_HIGH] += k - k0
    s.y = y
    s.base_x = base
    s.vec_p = vp
    nw = (w - p) // EVT3_WORD_BYTES
    n.words += nw
    nout[0] = k
    return nw


cdef class Evt3Decoder(Decoder):
    cdef Evt3State st
