# The float64 tracker kernel's state: one KState per springtrack.kernel.kernel.Kernel, read and
# written by the kernel's parts (docs/architecture.md, "The float64 kernel"):
#
#   kernel/index.pxd       spatial index: cells, box_*, bx_*, bcx ... syy_lim
#   kernel/activity.pxd    eq. (6): act, act_t0, act_span, the exp log act_n / act_i / act_arg
#   kernel/covariance.pxd  eq. (4)'s clamp: covariances and their inverses ia, ib2, ic
#   kernel/step.pxd        eqs. (2)-(5): means, covariances, the counters
#   kernel/springs.pyx     eqs. (7)-(22) per instance: connections, their precomputed
#                     coefficients, energies, the similarity frames, the sensitivity
#                     words; the state guard (rest_*, pos_*, n_resets)
#   kernel/kernel.pyx       loads the models and parameters into it; samples it (ksnapshot)
#
# Several model instances (springtrack.instances) side by side: instance g owns trackers
# [g_t0[g], g_t1[g]) and connections [g_c0[g], g_c1[g]), whose ends are its own trackers.
# An instance has at most MAX_TRACKERS = 64 trackers, so its masks (eqs. 21-22, the fit
# set of the similarity frame) are one 64-bit word relative to its first tracker; the
# event assignment's masks (sensitive, the spatial index's cells) span all n trackers in
# nw = ceil(n / 64) words, tracker i at bit i & 63 of word i >> 6.
#
# Plain C (structure of arrays, fixed capacities), so that the per-event code runs on it
# without the GIL and allocates nothing; the capacities are springtrack/limits.py's
# (checked when springtrack.kernel.kernel is imported).
from libc.stdint cimport int64_t, uint64_t

cdef enum:
    MAX_TRACKERS = 64          # of one instance (one mask word)
    MAX_CONNECTIONS = 128      # of one instance
    MAX_INSTANCES = 16
    MAX_SET_TRACKERS = 256     # of all instances
    MAX_SET_CONNECTIONS = 512
    MAX_WORDS = 4              # MAX_SET_TRACKERS / 64: the event assignment's mask words
    # the arrays' lengths: st_fit_frame (csrc/springs.h) reads the per-tracker ones in
    # lanes of 4 from an instance's first tracker, up to 3 entries beyond the last
    # tracker (kept finite: 0); and a length of a power of two (2 or 4 KiB) would put the
    # same entry of every array in the same L1 cache set (4 KiB aliasing), which the
    # per-event step, touching some 20 arrays at one index, pays for in conflict misses:
    # 8 more entries (one 64-byte line) shift each array's sets by one
    TRACKER_PAD = MAX_SET_TRACKERS + 8
    CONN_PAD = MAX_SET_CONNECTIONS + 8
    CELL_SHIFT = 3             # spatial index cells of 8 x 8 px
    ACT_LOG = 256              # eq. (6) increments logged before their exps run as a batch

cdef enum:
    K_NO_TRACKER = -1
    K_BACK_IN_TIME = -2
    K_OUT_OF_SENSOR = -3

cdef enum:
    # an instance's state (springtrack.instances.InstanceState; kernel/kernel.pyx checks)
    K_SEARCHING = 0
    K_TRACKING = 1
    K_LOST = 2

ctypedef struct KState:
    # geometry and size: n trackers, nc connections, ni instances, nw mask words
    int n, nc, ni, nw, width, height
    # the instances: trackers [g_t0, g_t1), connections [g_c0, g_c1); the instance of
    # each tracker; each instance's state (K_SEARCHING, K_TRACKING, K_LOST)
    int g_t0[MAX_INSTANCES]
    int g_t1[MAX_INSTANCES]
    int g_c0[MAX_INSTANCES]
    int g_c1[MAX_INSTANCES]
    int inst[TRACKER_PAD]
    int state[MAX_INSTANCES]
    # parameters shared by all instances (springtrack.instances.SHARED_PARAMS)
    double gate, tau, act_thr, smin2, smax2
    int period
    # each tracker's gains of eqs. (3)-(4), from its instance's parameters, side by side
    # (one cache line read per update): gain[i] = alpha_position, 1 - alpha_covariance,
    # alpha_covariance / covariance_bias, 0
    double gain[TRACKER_PAD][4]
    # each instance's criteria (INSTANCE_PARAMS)
    double energy_scale[MAX_INSTANCES]
    double energy_gain[MAX_INSTANCES]
    int ekind[MAX_INSTANCES]
    int need_torsion[MAX_INSTANCES]
    int pull_sim[MAX_INSTANCES]      # eq. (22) / eqs. (18)-(20) in the similarity frame
    int car_sim[MAX_INSTANCES]
    # the models' means and covariances (the state starts from them and the guard resets
    # an instance to them), and the position box (springtrack.limits.position_box): after
    # a spring update every mean lies in it, or the guard resets its instance (guard_state)
    double rest_x[TRACKER_PAD]
    double rest_y[TRACKER_PAD]
    double rest_sxx[TRACKER_PAD]
    double rest_sxy[TRACKER_PAD]
    double rest_syy[TRACKER_PAD]
    double pos_lo_x, pos_hi_x, pos_lo_y, pos_hi_y
    # the motion model (reference.py, eqs. M1-M8; parameters shared by all instances):
    # H (us), tau_m (0: off), q = 1 / tau_m^3, the velocity variance's bound 1 / tau_m^2,
    # c_h, the half offset's bound
    double horizon, tau_m, q_m, vv_max, c_h, h_max
    # tracker state, structure of arrays
    double mx[TRACKER_PAD]
    double my[TRACKER_PAD]
    double sxx[TRACKER_PAD]
    double sxy[TRACKER_PAD]
    double syy[TRACKER_PAD]
    double ia[TRACKER_PAD]          # inverse covariance [ia ib; ib ic]
    double ib2[TRACKER_PAD]         # 2 * ib
    double ic[TRACKER_PAD]
    double act[TRACKER_PAD]          # activity at act_t0 (see kactivity)
    # the motion model per tracker: velocity (px/us), half offset between the ON and OFF
    # edges (px), the Kalman covariance of eq. (M3) and 1 / alpha_position (its gain's
    # bound), the time the mean refers to and the time of its last event (us)
    double vx[TRACKER_PAD]
    double vy[TRACKER_PAD]
    double hx[TRACKER_PAD]
    double hy[TRACKER_PAD]
    double fon[TRACKER_PAD]          # ON share of its events (tau_m = 0: eq. M6b)
    double kpp[TRACKER_PAD]
    double kpv[TRACKER_PAD]
    double kvv[TRACKER_PAD]
    double inv_a1[TRACKER_PAD]
    int64_t tm[TRACKER_PAD]
    int64_t tk[TRACKER_PAD]
    int64_t act_t0, act_span
    # eq. (6) increments not yet added (see log_activity): tracker and exponent
    int act_n
    int act_i[ACT_LOG]
    double act_arg[ACT_LOG]
    double inv_tau
    double mass[TRACKER_PAD]
    double gdx0[TRACKER_PAD]
    double gdy0[TRACKER_PAD]
    # per instance: sum of its masses in index order (eq. 22's G); its trackers without a
    # connection, and those that may take events (eq. 21), bit i - g_t0 of one word
    double mass_sum[MAX_INSTANCES]
    uint64_t isolated[MAX_INSTANCES]
    uint64_t isens[MAX_INSTANCES]
    # the instances' isens side by side (compose_sensitive): bit i & 63 of word i >> 6 set
    # if tracker i may take events; what eq. (2) scans
    uint64_t sensitive[MAX_WORDS]
    # connections
    int ca[CONN_PAD]
    int cb[CONN_PAD]
    int kinds[CONN_PAD]       # bit 1 euclidean, 2 torsional, 4 cartesian
    uint64_t ends[CONN_PAD]   # bits ca[k], cb[k] less the instance's g_t0
    double stiff[CONN_PAD]
    double l0[CONN_PAD]
    double th0[CONN_PAD]
    double dx0[CONN_PAD]
    double dy0[CONN_PAD]
    # per-connection coefficients precomputed from stiff/kinds/th0 (branch-free springs):
    # half_a = a / 2; a_euc, a_tor, a_car = a where the spring has that kind, else 0;
    # c0, s0 = cos, sin of th0 (direction of eq. 11 when both ends coincide)
    double half_a[CONN_PAD]
    double a_euc[CONN_PAD]
    double a_tor[CONN_PAD]
    double a_car[CONN_PAD]
    double c0[CONN_PAD]
    double s0[CONN_PAD]
    double wa[CONN_PAD]       # 1 / mass of end a, of end b
    double wb[CONN_PAD]
    # eq. (14) measured from the rest direction: (rdx, rdy) = (dx0, dy0), or (c0, s0)
    # if that is 0; dth_zero = wrap(-th0), the reference's value when both ends coincide
    double rdx[CONN_PAD]
    double rdy[CONN_PAD]
    double dth_zero[CONN_PAD]
    # eq. (14)'s fast frame per instance (see set_frame): the rest directions turned by
    # frame_phi
    double frame_phi[MAX_INSTANCES]
    double qdx[CONN_PAD]
    double qdy[CONN_PAD]
    double energy[3][CONN_PAD]
    double mean_energy[MAX_INSTANCES]
    # each instance's similarity frame of the last spring update (st_fit_frame): s R =
    # [[sim_c, -sim_s], [sim_s, sim_c]] and sim_g, the image of the rest centre of mass
    double sim_c[MAX_INSTANCES]
    double sim_s[MAX_INSTANCES]
    double sim_gx[MAX_INSTANCES]
    double sim_gy[MAX_INSTANCES]
    # spatial index: the nw words at cells[(cy * gw + cx) * nw] have bit i set if tracker
    # i's gate box may cover the cell; box_* is the (margin-enlarged) box each tracker is
    # indexed with.
    uint64_t* cells
    int gw, gh
    int box_x0[TRACKER_PAD]
    int box_x1[TRACKER_PAD]
    int box_y0[TRACKER_PAD]
    int box_y1[TRACKER_PAD]
    double bx_lo[TRACKER_PAD]
    double bx_hi[TRACKER_PAD]
    double by_lo[TRACKER_PAD]
    double by_hi[TRACKER_PAD]
    # the per-update check (st_box_left): the box's centre, the slack left there for the
    # mean to move, and the variances up to which that slack holds
    double bcx[TRACKER_PAD]
    double bcy[TRACKER_PAD]
    double dev_x[TRACKER_PAD]
    double dev_y[TRACKER_PAD]
    # dev less the reach of eq. (M1)'s prediction, |v| H, at the tracker's last update:
    # what st_box_left tests the mean against
    double mdev_x[TRACKER_PAD]
    double mdev_y[TRACKER_PAD]
    double sxx_lim[TRACKER_PAD]
    double syy_lim[TRACKER_PAD]
    # counters
    int64_t last_t, n_valid, n_assigned, n_back, n_outside, n_spring_updates, n_reindex
    int64_t n_frame_misses, n_frame_moves
    int64_t n_resets                 # instance states the guard reset to the model
    # each instance's spring clock ([ref] step: it counts the valid events it takes and
    # those no tracker takes inside its spring box or inside none), kept so that an event
    # outside every box costs one count, not one per instance: n_free counts the valid
    # events no tracker took outside every box; instance g's update is due once n_free
    # reaches due[g], which each event it counts otherwise brings one nearer (its count =
    # period - (due[g] - n_free)); next_due is the smallest due[g]
    int64_t n_free, next_due
    int64_t due[MAX_INSTANCES]
    # each instance's spring box ([ref] _spring_box: whole pixels, x0, x1, y0, y1): an
    # event no tracker takes inside it counts on its clock as one of its own (due[g]); one
    # outside every box counts on every clock (n_free)
    int sbox[MAX_INSTANCES][4]
