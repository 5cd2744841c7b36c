# The float64 tracker kernel's state: one KState per springtrack._kernel.Kernel, read and
# written by the kernel's parts (docs/architecture.md, "The float64 kernel"):
#
#   _kindex.pxd       spatial index: cells, box_*, bx_*, bcx ... syy_lim
#   _kactivity.pxd    eq. (6): act, act_t0, act_span, the exp log act_n / act_i / act_arg
#   _kcovariance.pxd  eq. (4)'s clamp: covariances and their inverses ia, ib2, ic
#   _kstep.pxd        eqs. (2)-(5): means, covariances, the counters
#   _ksprings.pyx     eqs. (7)-(22): connections, their precomputed coefficients,
#                     energies, the similarity frame, sensitive_mask; the state guard
#                     (rest_*, pos_*, n_resets)
#   _kernel.pyx       loads the model and parameters into it; samples it (ksnapshot)
#
# Plain C (structure of arrays, fixed capacities), so that the per-event code runs on it
# without the GIL and allocates nothing; the capacities are springtrack/limits.py's
# (checked when springtrack._kernel is imported).
from libc.stdint cimport int64_t, uint64_t

cdef enum:
    MAX_TRACKERS = 64
    MAX_CONNECTIONS = 128
    CELL_SHIFT = 3             # spatial index cells of 8 x 8 px
    ACT_LOG = 256              # eq. (6) increments logged before their exps run as a batch

cdef enum:
    K_NO_TRACKER = -1
    K_BACK_IN_TIME = -2
    K_OUT_OF_SENSOR = -3

ctypedef struct KState:
    # geometry and model size
    int n, nc, width, height
    # parameters (derived constants precomputed by set_params)
    double a1, a2, keep, cov_gain, gate, tau, act_thr, energy_scale, energy_gain
    double smin2, smax2
    int period, ekind, need_torsion
    int pull_sim, car_sim            # eq. (22) / eqs. (18)-(20) in the similarity frame
    # the model's means and covariances (the state starts from them and the guard resets it
    # to them), and the position box (springtrack.limits.position_box): after a spring
    # update every mean lies in it, or the guard resets the state (guard_state)
    double rest_x[MAX_TRACKERS]
    double rest_y[MAX_TRACKERS]
    double rest_sxx[MAX_TRACKERS]
    double rest_sxy[MAX_TRACKERS]
    double rest_syy[MAX_TRACKERS]
    double pos_lo_x, pos_hi_x, pos_lo_y, pos_hi_y
    # tracker state, structure of arrays
    double mx[MAX_TRACKERS]
    double my[MAX_TRACKERS]
    double sxx[MAX_TRACKERS]
    double sxy[MAX_TRACKERS]
    double syy[MAX_TRACKERS]
    double ia[MAX_TRACKERS]          # inverse covariance [ia ib; ib ic]
    double ib2[MAX_TRACKERS]         # 2 * ib
    double ic[MAX_TRACKERS]
    double act[MAX_TRACKERS]          # activity at act_t0 (see kactivity)
    int64_t act_t0, act_span
    # eq. (6) increments not yet added (see log_activity): tracker and exponent
    int act_n
    int act_i[ACT_LOG]
    double act_arg[ACT_LOG]
    double inv_tau
    double mass[MAX_TRACKERS]
    double mass_sum                  # sum of mass[i] in index order (eq. 22's G)
    double gdx0[MAX_TRACKERS]
    double gdy0[MAX_TRACKERS]
    uint64_t isolated                # bit i set: tracker i has no connection
    uint64_t sensitive_mask          # bit i set: tracker i may take events (eq. 21)
    # connections
    int ca[MAX_CONNECTIONS]
    int cb[MAX_CONNECTIONS]
    int kinds[MAX_CONNECTIONS]       # bit 1 euclidean, 2 torsional, 4 cartesian
    uint64_t ends[MAX_CONNECTIONS]   # bits ca[k] and cb[k]: the trackers connection k links
    double stiff[MAX_CONNECTIONS]
    double l0[MAX_CONNECTIONS]
    double th0[MAX_CONNECTIONS]
    double dx0[MAX_CONNECTIONS]
    double dy0[MAX_CONNECTIONS]
    # per-connection coefficients precomputed from stiff/kinds/th0 (branch-free springs):
    # half_a = a / 2; a_euc, a_tor, a_car = a where the spring has that kind, else 0;
    # c0, s0 = cos, sin of th0 (direction of eq. 11 when both ends coincide)
    double half_a[MAX_CONNECTIONS]
    double a_euc[MAX_CONNECTIONS]
    double a_tor[MAX_CONNECTIONS]
    double a_car[MAX_CONNECTIONS]
    double c0[MAX_CONNECTIONS]
    double s0[MAX_CONNECTIONS]
    double wa[MAX_CONNECTIONS]       # 1 / mass of end a, of end b
    double wb[MAX_CONNECTIONS]
    # eq. (14) measured from the rest direction: (rdx, rdy) = (dx0, dy0), or (c0, s0)
    # if that is 0; dth_zero = wrap(-th0), the reference's value when both ends coincide
    double rdx[MAX_CONNECTIONS]
    double rdy[MAX_CONNECTIONS]
    double dth_zero[MAX_CONNECTIONS]
    # eq. (14)'s fast frame (see set_frame): the rest directions turned by frame_phi
    double frame_phi
    double qdx[MAX_CONNECTIONS]
    double qdy[MAX_CONNECTIONS]
    double energy[3][MAX_CONNECTIONS]
    double mean_energy
    # the similarity frame of the last spring update (st_fit_frame): s R = [[sim_c, -sim_s],
    # [sim_s, sim_c]] and sim_g, the image of the rest centre of mass
    double sim_c, sim_s, sim_gx, sim_gy
    # spatial index: cells[cy * gw + cx] has bit i set if tracker i's gate box may cover
    # the cell; box_* is the (margin-enlarged) box each tracker is indexed with.
    uint64_t* cells
    int gw, gh
    int box_x0[MAX_TRACKERS]
    int box_x1[MAX_TRACKERS]
    int box_y0[MAX_TRACKERS]
    int box_y1[MAX_TRACKERS]
    double bx_lo[MAX_TRACKERS]
    double bx_hi[MAX_TRACKERS]
    double by_lo[MAX_TRACKERS]
    double by_hi[MAX_TRACKERS]
    # the per-update check (st_box_left): the box's centre, the slack left there for the
    # mean to move, and the variances up to which that slack holds
    double bcx[MAX_TRACKERS]
    double bcy[MAX_TRACKERS]
    double dev_x[MAX_TRACKERS]
    double dev_y[MAX_TRACKERS]
    double sxx_lim[MAX_TRACKERS]
    double syy_lim[MAX_TRACKERS]
    # counters
    int64_t last_t, n_valid, n_assigned, n_back, n_outside, n_spring_updates, n_reindex
    int64_t n_frame_misses, n_frame_moves
    int64_t n_resets                 # states the guard reset to the model
    int since_spring
