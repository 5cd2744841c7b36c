# Snapshot rows written by the C-level tracker loops (_kernel, _fixed, firmware_sim._fused):
# one struct of raw pointers into numpy arrays made by sample_buffers(), so a nogil loop
# can append rows without touching a Python object.
from libc.stdint cimport int64_t, uint8_t
from springtrack.track cimport TrackRow

cdef struct SampleOut:
    int64_t* t                # (cap,) sample time, µs
    TrackRow* trackers        # (cap, n) the trackers' states (springtrack.track.TRACK_DTYPE)
    double* energy            # (cap, 3): mean energy of each kind
    uint8_t* wire             # (cap, n * 8) TELEMETRY tracker records (wire.TELE_TRACKER)
                              # written by kernels that pack them natively, or NULL
    Py_ssize_t cap, count

cdef dict sample_buffers(Py_ssize_t cap, int n, SampleOut* o, bint wire=*)
cdef dict bind_buffers(dict bufs, int n, SampleOut* o)
cdef dict take_samples(dict bufs, SampleOut* o, bint copy)
