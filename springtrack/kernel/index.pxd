# The float64 kernel's spatial index: which trackers an event's 8 x 8 px cell may concern.
#
# The nw words at cells[(cy * gw + cx) * nw] have bit i & 63 of word i >> 6 set if tracker
# i's gate box (|dx| <= sqrt(gate * sxx), |dy| <= sqrt(gate * syy): the region where
# eq. (2)'s d^2 < gate) may cover the cell.
# A tracker outside an event's cell cannot take the event, so scanning only the cell's
# candidates in index order (kernel/step.pxd assign_event) finds exactly the full scan's winner.
#
# A gate box is indexed enlarged by ST_INDEX_GROW of itself plus ST_INDEX_MARGIN px, so
# that a mean jittering by a fraction of sigma (alpha_position = 0.2 moves it ~0.3 sigma)
# does not re-index every few events.  Any enlargement keeps the scan exact; these only
# trade re-indexing against candidates (docs/benchmarks.md, "Where the time goes").
# After each update a cheap sufficient test (st_box_left, csrc/springs.h) re-indexes a
# tracker once its sigmas have grown by ST_INDEX_SIGMA_SLACK or its mean has moved by what
# that growth leaves of the enlargement: four comparisons instead of the exact gate box,
# for re-indexing a little earlier than needed.
#
# eq. (M1) predicts a mean up to |v| H along its velocity: the box is enlarged by that reach
# (and ST_INDEX_GROW of it), and the mean is tested against dev less the reach of its
# current velocity (mdev_x, mdev_y, set by set_reach at each update).
#
# cdef inline: compiled into each module that cimports it (the per-event step in
# springtrack.kernel.kernel, the springs in springtrack.kernel.springs), so the step inlines it.
from libc.math cimport sqrt, floor, fabs
from libc.stdint cimport int64_t, uint64_t

from springtrack.kernel.state cimport KState, CELL_SHIFT

cdef extern from *:
    """
    /* springtrack/kernel/index.pxd: the enlargement of an indexed gate box */
    #define ST_INDEX_MARGIN 3.0
    #define ST_INDEX_GROW 0.25
    #define ST_INDEX_SIGMA_SLACK 0.05
    """
    const double ST_INDEX_MARGIN        # px
    const double ST_INDEX_GROW          # of the gate box's half-width
    const double ST_INDEX_SIGMA_SLACK   # of sigma

cdef extern from "springtrack/csrc/springs.h" nogil:
    int64_t st_box_left(double mx, double my, double sxx, double syy, double bcx, double bcy,
                        double dev_x, double dev_y, double sxx_lim, double syy_lim)


cdef inline void index_set(KState* s, int i, int x0, int x1, int y0, int y1, bint on) noexcept nogil:
    # tracker i is bit i & 63 of word i >> 6 of each cell's nw words
    cdef int cx, cy, nw = s.nw
    cdef uint64_t bit = (<uint64_t>1) << (i & 63)
    cdef uint64_t* word = s.cells + (i >> 6)
    for cy in range(y0, y1 + 1):
        for cx in range(x0, x1 + 1):
            if on:
                word[(cy * s.gw + cx) * nw] |= bit
            else:
                word[(cy * s.gw + cx) * nw] &= ~bit


cdef inline int cell_of(const KState* s, double v, int gmax) noexcept nogil:
    # floor division of a pixel coordinate by the cell size, clamped to the grid
    cdef double c = floor(v / (1 << CELL_SHIFT))
    if not c >= 0.0:                   # below the grid, or not a number
        return 0
    if c > gmax:
        return gmax
    return <int>c


cdef inline void reindex(KState* s, int i) noexcept nogil:
    """(Re)insert tracker i with its current gate box enlarged by ST_INDEX_GROW and
    ST_INDEX_MARGIN, and set the slack of st_box_left: the gate box may grow by
    ST_INDEX_SIGMA_SLACK (sigma, i.e. the variances by its square) and the mean move by
    what is then left of the enlargement; shrunk by 1e-9 relative so rounding can never
    make the test miss."""
    cdef double gx = sqrt(s.gate * s.sxx[i]), gy = sqrt(s.gate * s.syy[i])
    cdef double rx = fabs(s.vx[i]) * s.horizon * (1.0 + ST_INDEX_GROW)   # eq. (M1)'s reach
    cdef double ry = fabs(s.vy[i]) * s.horizon * (1.0 + ST_INDEX_GROW)
    cdef double hx = gx * (1.0 + ST_INDEX_GROW) + ST_INDEX_MARGIN + rx
    cdef double hy = gy * (1.0 + ST_INDEX_GROW) + ST_INDEX_MARGIN + ry
    cdef double grow2 = ((1.0 + ST_INDEX_SIGMA_SLACK) * (1.0 + ST_INDEX_SIGMA_SLACK)
                         * (1.0 - 1e-9))
    s.bx_lo[i] = s.mx[i] - hx
    s.bx_hi[i] = s.mx[i] + hx
    s.by_lo[i] = s.my[i] - hy
    s.by_hi[i] = s.my[i] + hy
    s.bcx[i] = s.mx[i]
    s.bcy[i] = s.my[i]
    s.dev_x[i] = (gx * (ST_INDEX_GROW - ST_INDEX_SIGMA_SLACK) + ST_INDEX_MARGIN + rx) * (1.0 - 1e-9)
    s.dev_y[i] = (gy * (ST_INDEX_GROW - ST_INDEX_SIGMA_SLACK) + ST_INDEX_MARGIN + ry) * (1.0 - 1e-9)
    set_reach(s, i)
    s.sxx_lim[i] = s.sxx[i] * grow2
    s.syy_lim[i] = s.syy[i] * grow2
    index_set(s, i, s.box_x0[i], s.box_x1[i], s.box_y0[i], s.box_y1[i], False)
    s.box_x0[i] = cell_of(s, s.bx_lo[i], s.gw - 1)
    s.box_x1[i] = cell_of(s, s.bx_hi[i], s.gw - 1)
    s.box_y0[i] = cell_of(s, s.by_lo[i], s.gh - 1)
    s.box_y1[i] = cell_of(s, s.by_hi[i], s.gh - 1)
    index_set(s, i, s.box_x0[i], s.box_x1[i], s.box_y0[i], s.box_y1[i], True)
    s.n_reindex += 1


cdef inline void set_reach(KState* s, int i) noexcept nogil:
    """The mean's slack less eq. (M1)'s reach at tracker i's velocity (rounded up by 1e-9
    relative, so rounding never makes the test miss)."""
    s.mdev_x[i] = s.dev_x[i] - fabs(s.vx[i]) * s.horizon * (1.0 + 1e-9)
    s.mdev_y[i] = s.dev_y[i] - fabs(s.vy[i]) * s.horizon * (1.0 + 1e-9)


cdef inline void check_index(KState* s, int i) noexcept nogil:
    """Re-index tracker i if its exact gate box, anywhere along eq. (M1)'s prediction,
    may have left the box it is indexed with."""
    set_reach(s, i)
    if st_box_left(s.mx[i], s.my[i], s.sxx[i], s.syy[i], s.bcx[i], s.bcy[i], s.mdev_x[i],
                   s.mdev_y[i], s.sxx_lim[i], s.syy_lim[i]):
        reindex(s, i)
