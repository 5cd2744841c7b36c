"""The executable specification: Algorithm 1 of Valeiras et al. 2015, float64, one event at a time.

Every line cites the equation it implements.  The Cython kernel (``kernel/kernel.pyx``) translates
this file and must agree with it to 1e-9 px (tests/test_springtrack/kernel/test_equivalence.py); keep the two in
step.  The kernel keeps this file's order of floating-point operations in the per-event
step (so ties resolve alike) but evaluates exp (eqs. 2, 6) and the springs' atan2, sin and
cos with its own ~1-ulp code (springtrack/csrc/fastmath.h), and sums the three spring kinds
per connection first, so the two differ by rounding.  No ``**``, no ``math.hypot`` here
(CPython's hypot is not libm's).

Interpretation choices (docs/algorithm.md explains them):

* eqs. (3)-(4): ``alpha_position`` / ``alpha_covariance`` weight the NEW event.
* eq. (2): the threshold applies to the unnormalised kernel ``exp(-d^2/2)``, i.e. an
  event may join tracker i only inside its gate ``d_i^2 < -2 ln(p_threshold)``; the
  winner is the sensitive tracker with the smallest Mahalanobis distance d^2 (ties:
  lowest index).  The activity increment of eq. (6) is that same kernel value.
* eq. (5): the covariance sample is taken about the mean BEFORE the update of eq. (3)
  and divided by the gate's truncation factor (see :func:`springtrack.gate.covariance_bias`), so a
  tracker's ellipse converges to its blob's covariance instead of collapsing.
* Springs run every ``spring_period`` valid events (paper: 55; with several instances,
  events of the instance's own clock, below): all spring displacements are computed from
  the same positions, then applied (Jacobi order); energies are those of the positions
  before the displacement.
* eqs. (21)-(22) use strict ``E > s * mean(E)`` so a model at rest (all E = 0) is
  neither pulled nor insensitive; a tracker is pulled by eq. (22) at most once per
  spring update, however many of its connections exceed the threshold.
* ``pull_frame`` / ``cartesian_frame`` = "similarity": once per spring update, after the
  spring step, the similarity (scale s, rotation R, translation) that best maps the rest
  shape onto the trackers is fitted (mass-weighted Procrustes, ``fit_frame``) over the
  trackers no over-threshold connection touches, then refitted with each tracker weighted
  by how well it agrees with it (its squared distance to where the frame puts it against
  ``s`` times the fit set's weighted mean: eq. (21)'s test on the frame's residuals, made
  continuous, up to ``FRAME_REFITS`` times): a part pulled away, occluded or sliding moves
  neither the frame nor, through it, the others.  Eq. (22) pulls a tracker at an
  over-threshold connection toward ``G + s R dG0``, and the others by the share they
  disagree with the frame (eq. 21's sensitivity stays the connections' verdict); the
  Cartesian springs of the next update hold the rest offset ``s R d0``.
* The motion model (this project's extension, eqs. M1-M9; docs/motion.md; off by
  default): each tracker keeps a velocity v, the half offset h between its part's ON
  and OFF edges, the time t_m its mean refers to and the covariance P of a Kalman filter
  of its position and velocity (per axis, in units of the event spread).  An event is
  gated and weighed (eq. 2) about the mean predicted to its time (M1); the winner's gains
  (M3) come from P (at most alpha1 for the mean): they fall where its events come fast;
  its mean, half offset and velocity move by the event's residual about the edge of its
  polarity (M4-M7); the springs act on the means predicted to the update's time, and
  eq. (22)'s pull takes a pulled tracker's velocity toward its structure's (M8) and its
  half offset toward 0 by the same gain (M9).  With
  motion_tau_us = 0 and polarity_gain = 0 this is the paper's Algorithm 1 exactly.
* Several model instances (springtrack.instances): their trackers side by side; eq. (2)'s
  argmin runs over the union of the sensitive trackers (ties: lowest index, the first
  instance); springs, eq. (13)'s mean energy, eqs. (21)-(22), the centre of mass and the
  similarity frame per instance, each with its own parameters of INSTANCE_PARAMS; only
  tracking instances are sensitive and run their springs (``set_state``; the loss rule
  that decides a state is springtrack.acquisition.loss, the same for every backend).
  Each instance has its own spring clock: it counts the valid events its trackers take
  and those no tracker takes inside its spring box (the box of its means at its last
  spring update, SPRING_BOX_PX around; before its first update, every event); an event
  no tracker takes inside no box counts on every clock.  When a count reaches
  ``spring_period`` that instance's spring update runs (its springs, eq. (13)'s mean,
  eqs. (21)-(22) and frame if it is tracking; then the state guard of its trackers; then
  its box) and its count restarts.  So an object's springs keep their pace per its own
  events and its surroundings' whether or not other objects are in view, and N
  instances do not do N times one instance's spring work; with one instance the clock
  counts every valid event (the paper's rule).  A searching or lost instance's trackers
  take no event, so its clock counts the events near them and those near no instance;
  its updates run the guard only; ``set_state``, ``place``, ``move`` and ``relocate``
  leave its count and its box as they are.  Several clocks due at one event run in
  instance order.
"""
from __future__ import annotations

import math

import numpy as np

from .gate import RHO_MAX, covariance_bias
from .instances import TRACKING, ModelSet, per_instance
from .limits import position_box
from .model import SPRING_BIT, ShapeModel
from .params import ENERGY_KINDS, Params
from .sampling import UNSET, first_sample_time, next_sample, sample_due

EUCLIDEAN, TORSIONAL, CARTESIAN = SPRING_BIT["euclidean"], SPRING_BIT["torsional"], SPRING_BIT["cartesian"]
TWO_PI = 2.0 * math.pi
# The similarity frame (fit_frame): its scale is held to [FRAME_SCALE_MIN, FRAME_SCALE_MAX]
# (a structure collapsed onto a point or blown apart has lost its object: the frame then
# keeps a plausible size instead of following it), and a fit set whose rest shape spreads
# less than FRAME_MIN_SPREAD px^2 (mass-weighted mean square about its centroid, 2^-20:
# about 1e-3 px RMS) cannot tell a rotation, so the frame is the identity there.
FRAME_SCALE_MIN = 0.25
FRAME_SCALE_MAX = 4.0
FRAME_MIN_SPREAD = 2.0 ** -20
# Refits of the frame weighted by how well each tracker agrees with it (fit_frame): two
# find a pulled part and then a second one the first fit hid.
FRAME_REFITS = 2
# A residual no larger than FRAME_AGREE_PX2 (px^2: 1/4 px) always agrees fully: below it
# the residuals are the means' rounding and jitter, not a part that left its place.
FRAME_AGREE_PX2 = 2.0 ** -4
# A tracker's weight in the refit falls from 1 at its threshold T to 0 at
# (1 + FRAME_RAMP) T (fit_frame): continuous, so that kernels whose means differ by
# rounding fit the same frame, and narrow, so that a part that left its place drops out.
# Shallow enough, too: its slope multiplies a difference in a mean on the ramp at every
# spring update (a tracker near T feeds the fit and eq. (22) by 1 - v), so a steeper ramp
# lets the float and integer kernels' roundings grow apart (1/4 parted them by 2.8 px on
# the pulled grid's corner, 1/2 keeps them within 5e-6 px: docs/algorithm.md (e)).
FRAME_RAMP = 2.0 ** -1

# Each instance's spring box (step): the events no tracker takes within SPRING_BOX_PX of
# the box of its means count on its spring clock; before its first spring update, every
# event (the box reaching SPRING_BOX_ALL px each way)
SPRING_BOX_PX = 16
SPRING_BOX_ALL = 1 << 30

# Result codes of step(): >= 0 is the index of the tracker that took the event.
NO_TRACKER = -1          # valid event, no sensitive tracker within its gate
SKIPPED_BACK_IN_TIME = -2
SKIPPED_OUT_OF_SENSOR = -3

# The motion model's bounds: a velocity is held to |v_x|, |v_y| <= VELOCITY_MAX px/us
# (250,000 px/s: a part faster than that crosses a 1280-px sensor in 5 ms), a half offset
# between the edges to |h_x|, |h_y| <= sigma_max_px.  A placed tracker's Kalman position
# variance is P_UNKNOWN (one event spread: placed on its part), its velocity taken as still.
VELOCITY_MAX = 0.25
P_UNKNOWN = 1.0


def wrap_angle(a: float) -> float:
    """Map an angle in [-3 pi, 3 pi) to [-pi, pi) (differences of two atan2 results)."""
    if a >= math.pi:
        return a - TWO_PI
    if a < -math.pi:
        return a + TWO_PI
    return a


class ReferenceTracker:
    """Float64 reference tracker; state in plain Python lists, one event per call.

    ``ReferenceTracker(model, params)``: one ShapeModel and its resolved Params, or a
    ``springtrack.instances.ModelSet`` (params None: each instance's own)."""

    def __init__(self, model, params: Params | None = None):
        if isinstance(model, ModelSet):
            mset = model if params is None else model.with_params(params)
        else:
            mset = ModelSet([model], params if params is not None else Params())
        self.mset = mset
        self.model = mset[0].model
        arr = mset.arrays()
        self.n = mset.n
        self.nc = mset.nc
        self.ni = len(mset)
        self.width, self.height = mset.width, mset.height
        # instances: trackers [t0, t1), connections [c0, c1)
        self.t0 = [int(v) for v in arr["inst_t0"]]
        self.t1 = [int(v) for v in arr["inst_t1"]]
        self.c0 = [int(v) for v in arr["inst_c0"]]
        self.c1 = [int(v) for v in arr["inst_c1"]]
        self.inst = [g for g in range(self.ni) for _ in range(self.t0[g], self.t1[g])]
        # the models' state, which the tracker state starts from and an instance is reset to
        self.rest = tuple([float(v) for v in arr[k]] for k in ("x", "y", "sxx", "sxy", "syy"))
        # where trackers may be after a spring update (the state guard, _guard)
        self.box = position_box(self.width, self.height)
        # tracker state
        self.mx, self.my, self.sxx, self.sxy, self.syy = (list(v) for v in self.rest)
        self.act = [0.0] * self.n
        self.tlast = [0] * self.n
        # the motion model (eqs. M1-M9): velocity (px/us), half offset between the ON
        # and OFF edges (px), the time the mean refers to (us), the Kalman covariance
        # [[kpp, kpv], [kpv, kvv]] of position and velocity in units of the event spread
        self.vx = [0.0] * self.n
        self.vy = [0.0] * self.n
        self.hx = [0.0] * self.n
        self.hy = [0.0] * self.n
        # without a velocity (tau_m = 0), the ON share of the tracker's events at its
        # mean's gain: how far eq. (M6b) may tell its two edges apart
        self.fon = [0.5] * self.n
        self.tm = [0] * self.n
        self.kpp = [P_UNKNOWN] * self.n
        self.kpv = [0.0] * self.n
        self.kvv = [0.0] * self.n
        self.sensitive = [True] * self.n
        self.ia = [0.0] * self.n
        self.ib = [0.0] * self.n
        self.ic = [0.0] * self.n
        self.mass = [float(v) for v in arr["mass"]]
        self.inv_mass = [1.0 / float(v) for v in arr["mass"]]
        self.gdx0 = [float(v) for v in arr["gdx0"]]
        self.gdy0 = [float(v) for v in arr["gdy0"]]
        # connections
        self.ca = [int(v) for v in arr["ca"]]
        self.cb = [int(v) for v in arr["cb"]]
        self.kinds = [int(v) for v in arr["kinds"]]
        self.stiff = [float(v) for v in arr["stiffness"]]
        self.l0 = [float(v) for v in arr["l0"]]
        self.th0 = [float(v) for v in arr["th0"]]
        self.dx0 = [float(v) for v in arr["dx0"]]
        self.dy0 = [float(v) for v in arr["dy0"]]
        self.energy = [[0.0] * self.nc for _ in ENERGY_KINDS]   # [kind][connection]
        self.degree = [0] * self.n
        for k in range(self.nc):
            self.degree[self.ca[k]] += 1
            self.degree[self.cb[k]] += 1
        # per instance: eq. (13)'s mean energy, the similarity frame of the last spring
        # update (fit_frame: s R = [[fc, -fs], [fs, fc]], (fgx, fgy) where it maps the
        # rest centre of mass G0) and the state
        self.mean_energies = [0.0] * self.ni
        self.fc = [1.0] * self.ni
        self.fs = [0.0] * self.ni
        self.fgx = [0.0] * self.ni
        self.fgy = [0.0] * self.ni
        for g in range(self.ni):
            self._rest_frame(g)
        self.state = [int(TRACKING)] * self.ni
        # counters
        self.last_t = -(1 << 62)
        self.n_valid = self.n_assigned = self.n_back = self.n_outside = 0
        self.since_spring = [0] * self.ni            # each instance's spring clock
        A = SPRING_BOX_ALL
        self.sbox = [(-A, A, -A, A)] * self.ni        # and its spring box
        self.n_spring_updates = 0                    # instances' spring updates, summed
        self.n_resets = 0
        self.set_params(mset.params_list)

    def _reset_instance(self, g: int) -> None:
        """Instance g's state as its model gives it: means and covariances, no activity,
        its trackers sensitive if it is tracking, no energy, the similarity frame the
        identity at the rest centre of mass."""
        for i in range(self.t0[g], self.t1[g]):
            self.mx[i], self.my[i], self.sxx[i], self.sxy[i], self.syy[i] = (
                v[i] for v in self.rest)
            self.act[i] = 0.0
            self.tlast[i] = 0
            self._still(i)
            self.sensitive[i] = self.state[g] == TRACKING
            self._clamp_and_invert(i)
        for e in self.energy:
            for k in range(self.c0[g], self.c1[g]):
                e[k] = 0.0
        self.mean_energies[g] = 0.0
        self._rest_frame(g)

    def _still(self, i: int) -> None:
        """Tracker i's motion state as placed: still (up to the acceleration noise its
        first prediction adds), one edge, position unknown (its first gain is alpha1)."""
        self.vx[i] = self.vy[i] = self.hx[i] = self.hy[i] = 0.0
        self.fon[i] = 0.5
        self.tm[i] = 0
        self.kpp[i] = P_UNKNOWN
        self.kpv[i] = self.kvv[i] = 0.0

    def _rest_frame(self, g: int) -> None:
        """Instance g's frame before its first fit: the identity about G0 at rest."""
        t0 = self.t0[g]
        self.fc[g], self.fs[g] = 1.0, 0.0
        self.fgx[g] = self.mx[t0] - self.gdx0[t0]
        self.fgy[g] = self.my[t0] - self.gdy0[t0]

    @property
    def mean_energy(self) -> float:
        """eq. (13) of the first instance (:attr:`mean_energies`: every instance's)."""
        return self.mean_energies[0]

    @property
    def ekind(self) -> int:
        return self.ekinds[0]

    @property
    def params(self) -> Params:
        return self.plist[0]

    def set_params(self, params) -> None:
        """One Params for every instance, or one per instance (shared ones equal)."""
        plist = per_instance(params, self.ni)
        self.mset = self.mset.with_params(plist)
        p = plist[0]                               # SHARED_PARAMS: the same in all
        self.plist = plist
        self.gate = p.gate_d2
        if getattr(self, "tau", p.activity_tau_us) != p.activity_tau_us and self.n_valid:
            for i in range(self.n):      # eq. (6): a new tau decays from the change on
                self.act[i] = self.activity_at(i, self.last_t)
                self.tlast[i] = self.last_t
        self.tau = p.activity_tau_us
        self.act_thr = p.activity_threshold
        self.period = p.spring_period
        self.smin2 = p.sigma_min_px * p.sigma_min_px
        self.smax2 = p.sigma_max_px * p.sigma_max_px
        # the motion model (eqs. M1-M9): 0 turns each part off.  tau_m sets the Kalman
        # filter's acceleration noise q = 1 / tau_m^3 (event spreads^2 / us^3) and bounds
        # its velocity variance to 1 / tau_m^2 (a spread per tau_m)
        self.horizon = p.prediction_horizon_us
        self.tau_m = p.motion_tau_us
        tau = self.tau_m
        self.q_m = 1.0 / (tau * tau * tau) if tau > 0.0 else 0.0
        self.vv_max = 1.0 / (tau * tau) if tau > 0.0 else 0.0
        self.c_h = p.polarity_gain
        self.h_max = p.sigma_max_px
        # per tracker, from its instance: the gains of eqs. (3)-(5)
        self.a1 = [plist[g].alpha_position for g in self.inst]
        self.a2 = [plist[g].alpha_covariance for g in self.inst]
        # eq. (M3): 1 / alpha1, the bound of the mean's gain
        self.inv_a1 = [1.0 / max(a, 1e-6) for a in self.a1]
        self.cov_gain = [q.alpha_covariance / covariance_bias(q.alpha_position, q.gate_d2)
                         for q in (plist[g] for g in self.inst)]
        # per instance: the criteria and the frames
        self.ekinds = [q.energy_kind_index for q in plist]
        self.escale = [q.energy_scale for q in plist]
        self.egain = [q.energy_gain for q in plist]
        self.pull_sim = [q.pull_similarity for q in plist]
        self.car_sim = [q.cartesian_similarity for q in plist]
        self.need_torsion = [self.c1[g] > self.c0[g] and (
            self.ekinds[g] == 1 or any(self.kinds[k] & TORSIONAL for k in range(self.c0[g], self.c1[g])))
            for g in range(self.ni)]
        for i in range(self.n):          # new sigma bounds apply at once
            self._clamp_and_invert(i)

    # ---- per event -----------------------------------------------------------
    def predict_dt(self, i: int, t: int) -> float:
        """eq. (M1)'s lead: how long tracker i's mean is carried along its velocity from
        its time t_m to t, up to H after the tracker's last event t_k (a part that stops
        firing is not carried on): max(0, min(t, t_k + H) - t_m)."""
        return max(0.0, min(float(t), self.tlast[i] + self.horizon) - self.tm[i])

    def step(self, t: int, x: int, y: int, p: int = 1) -> int:
        """Process one event of polarity p (1 ON, 0 OFF); returns the winning tracker
        index or a NO_/SKIPPED_ code."""
        if t < self.last_t:
            self.n_back += 1
            return SKIPPED_BACK_IN_TIME
        self.last_t = t
        if x >= self.width or y >= self.height:
            self.n_outside += 1
            return SKIPPED_OUT_OF_SENSOR
        self.n_valid += 1
        fx = float(x)
        fy = float(y)
        # eq. (2) in the log domain: smallest Mahalanobis d^2 among sensitive trackers (of
        # every instance), accepted only inside the gate exp(-d^2/2) > p_threshold.
        best = NO_TRACKER
        best_d2 = self.gate
        for i in range(self.n):
            if not self.sensitive[i]:
                continue
            lead = self.predict_dt(i, t)
            dx = fx - (self.mx[i] + self.vx[i] * lead)              # eq. (M1): about the
            dy = fy - (self.my[i] + self.vy[i] * lead)              # predicted mean
            d2 = self.ia[i] * dx * dx + self.ic[i] * dy * dy + 2.0 * self.ib[i] * dx * dy
            if d2 < best_d2:
                best_d2 = d2
                best = i
        owner = -1
        if best >= 0:
            self._update(best, t, fx, fy, best_d2, p)
            self.n_assigned += 1
            owner = self.inst[best]
        # each instance's spring clock counts the events its trackers took and those no
        # tracker took inside its spring box (the box of its means at its last spring
        # update, SPRING_BOX_PX around); an event no tracker took outside every box counts
        # for every instance
        near = [owner == g or (owner < 0 and self.in_spring_box(g, x, y))
                for g in range(self.ni)]
        if owner < 0 and not any(near):
            near = [True] * self.ni
        for g in range(self.ni):
            if near[g]:
                self.since_spring[g] += 1
                if self.since_spring[g] >= self.period:
                    self.since_spring[g] = 0
                    self.spring_update(g)
        return best

    def _update(self, i: int, t: int, fx: float, fy: float, d2: float, pol: int) -> None:
        p = math.exp(-0.5 * d2)                                     # eq. (2), unnormalised
        # eq. (M1): the mean predicted to t from the tracker's last event before this one,
        # up to H after it: the mean eq. (2) gated the event about
        lead = self.predict_dt(i, t)
        if self.tau_m > 0.0:
            gain, kv = self._kalman(i, t)                            # eq. (M3)
        else:
            gain, kv = self.a1[i], 0.0                               # eq. (3)
        # eq. (6): activity decays exponentially since this tracker's last event
        self.act[i] = self.act[i] * math.exp(-(t - self.tlast[i]) / self.tau) + p
        self.tlast[i] = t
        px = self.mx[i] + self.vx[i] * lead                          # eq. (M1)
        py = self.my[i] + self.vy[i] * lead
        self.tm[i] = t
        dx = fx - px                                                 # eq. (5): offset from the
        dy = fy - py                                                 # pre-update (predicted) mean
        # eq. (M4): the residual about the edge of the event's polarity, m^ + s h
        sgn = 1.0 if pol else -1.0
        rx = dx - sgn * self.hx[i]
        ry = dy - sgn * self.hy[i]
        self.mx[i] = px + gain * rx                                  # eq. (M5) = eq. (3) when
        self.my[i] = py + gain * ry                                  # v = h = 0, gain = a1
        if self.c_h > 0.0:
            hmax = self.h_max
            if self.tau_m > 0.0:                                     # eq. (M6)
                self.hx[i] = min(max(self.hx[i] + self.c_h * gain * sgn * rx, -hmax), hmax)
                self.hy[i] = min(max(self.hy[i] + self.c_h * gain * sgn * ry, -hmax), hmax)
            else:
                # eq. (M6b): without a velocity the half offset takes only the balanced
                # share b of the residual and lets the rest of itself go:
                # f = f + K (on - f), b = 4 f (1 - f), h = h + c_h K (b s r - (1 - b) h)
                f = self.fon[i] + gain * ((1.0 if pol else 0.0) - self.fon[i])
                self.fon[i] = f
                b = 4.0 * f * (1.0 - f)
                ch = self.c_h * gain
                self.hx[i] = min(max(self.hx[i] + ch * (b * sgn * rx - (1.0 - b) * self.hx[i]),
                                     -hmax), hmax)
                self.hy[i] = min(max(self.hy[i] + ch * (b * sgn * ry - (1.0 - b) * self.hy[i]),
                                     -hmax), hmax)
        if self.tau_m > 0.0:                                         # eq. (M7)
            self.vx[i] = min(max(self.vx[i] + kv * rx, -VELOCITY_MAX), VELOCITY_MAX)
            self.vy[i] = min(max(self.vy[i] + kv * ry, -VELOCITY_MAX), VELOCITY_MAX)
        keep = 1.0 - self.a2[i]                                      # eq. (4), a2 = weight of dS,
        g = self.cov_gain[i]                                         # dS / covariance_bias
        self.sxx[i] = keep * self.sxx[i] + g * (dx * dx)
        self.sxy[i] = keep * self.sxy[i] + g * (dx * dy)
        self.syy[i] = keep * self.syy[i] + g * (dy * dy)
        self._clamp_and_invert(i)

    def _kalman(self, i: int, t: int) -> tuple:
        """eq. (M3): tracker i's Kalman filter of position and velocity (per axis, in units
        of its event spread: an event measures the position with variance 1; white
        acceleration noise q), predicted over dt = min(t - t_k, tau_m) since its last event,
        then updated by one event, whose variance is raised where needed to keep K_p <=
        alpha1 (the filter stays consistent: a less precise event, not a clipped gain).
        Returns the gains (K_p, K_v): mean and velocity (1/us)."""
        d = min(float(t - self.tlast[i]), self.tau_m)
        q = self.q_m
        # P^ = F P F^T + Q, F = [[1, dt], [0, 1]], Q = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]
        pp = self.kpp[i] + d * (2.0 * self.kpv[i] + d * self.kvv[i]) + q * (d * d * d) / 3.0
        pv = self.kpv[i] + d * self.kvv[i] + q * (d * d) * 0.5
        vv = min(self.kvv[i] + q * d, self.vv_max)                   # a spread per tau_m
        lim = math.sqrt(pp * vv)                                     # P^ positive
        pv = min(max(pv, -lim), lim)
        # S = H P^ H^T + R, R = max(1, pp (1 / alpha1 - 1)): K_p = pp / S <= alpha1
        inv_s = 1.0 / max(1.0 + pp, pp * self.inv_a1[i])
        kp = pp * inv_s                                              # K = P^ H^T / S
        kv = pv * inv_s
        self.kpp[i] = pp - kp * pp                                   # P = (I - K H) P^
        self.kpv[i] = pv - kp * pv
        self.kvv[i] = vv - kv * pv
        return kp, kv

    def _clamp_and_invert(self, i: int) -> None:
        """Bound sigma_x, sigma_y to [sigma_min, sigma_max] and |rho| to RHO_MAX, then keep
        the inverse covariance used by eq. (2)."""
        sxx = min(max(self.sxx[i], self.smin2), self.smax2)
        syy = min(max(self.syy[i], self.smin2), self.smax2)
        lim = RHO_MAX * math.sqrt(sxx * syy)
        sxy = min(max(self.sxy[i], -lim), lim)
        self.sxx[i], self.sxy[i], self.syy[i] = sxx, sxy, syy
        inv_det = 1.0 / (sxx * syy - sxy * sxy)                        # Sigma^-1 for eq. (2)
        self.ia[i] = syy * inv_det
        self.ib[i] = -sxy * inv_det
        self.ic[i] = sxx * inv_det

    # ---- springs and energy criteria (every spring_period events) ------------
    def fit_frame(self, calm: list, g: int = 0) -> dict:
        """Instance g's similarity frame (``_fit_similarity``) fitted to the trackers that
        agree with the structure, each weighted by how well it agrees; returns how much
        each disagrees.

        Fit set F: the trackers ``calm`` marks (indexed like all trackers) -- at a spring
        update, those no connection over the energy threshold touches (eqs. 21-22 leave
        them alone) -- or all of the instance's trackers if fewer than 2; each agrees fully
        (v_i = 1).  Then, up to FRAME_REFITS times: each tracker's squared residual
        r_i^2 = |mu_i - (G + s R dG0_i)|^2 and eq. (21)'s test with the criteria's scale s
        on them, made continuous: with T = max(s sum_F m v r^2 / sum_F m v,
        FRAME_AGREE_PX2), v_i = 1 for r_i^2 <= T, 0 from (1 + FRAME_RAMP) T, linear
        between (a tracker
        near the threshold moves the frame by little either way, so kernels whose means
        differ by rounding fit the same frame); if the v changed and at least 2 are
        positive, the frame is refitted with masses m v.  With s at or above the
        instance's connection count no connection is ever over the threshold and no
        tracker is tested (as the criteria, which never act then).  Returns
        {i: 1 - v_i} for the trackers of F (eq. 22 pulls tracker i by that share)."""
        mine = range(self.t0[g], self.t1[g])
        fit = [i for i in mine if calm[i]]
        if len(fit) < 2:
            fit = list(mine)
        wt = {i: 1.0 for i in fit}
        self._fit_similarity(fit, wt, g)
        if not self.escale[g] < self.c1[g] - self.c0[g]:
            return {}
        for _ in range(FRAME_REFITS):
            c, sn, gx, gy = self.fc[g], self.fs[g], self.fgx[g], self.fgy[g]
            r2 = {}
            w = total = 0.0
            for i in fit:
                ex = self.mx[i] - (gx + (c * self.gdx0[i] - sn * self.gdy0[i]))   # mu - (G + s R dG0)
                ey = self.my[i] - (gy + (sn * self.gdx0[i] + c * self.gdy0[i]))
                r2[i] = ex * ex + ey * ey
                m = self.mass[i] * wt[i]
                w += m
                total += m * r2[i]
            thr = max(self.escale[g] * (total / w), FRAME_AGREE_PX2)  # eq. (21)'s test on r^2
            new = {i: min(max(1.0 - (r2[i] - thr) / (FRAME_RAMP * thr), 0.0), 1.0) for i in fit}
            if new == wt or sum(1 for i in fit if new[i] > 0.0) < 2:
                break
            wt = new
            self._fit_similarity([i for i in fit if wt[i] > 0.0], wt, g)
        return {i: 1.0 - wt[i] for i in fit}

    def _fit_similarity(self, fit: list, wt: dict, g: int) -> None:
        """The similarity x -> G + s R (x - G0) that best maps the rest shape of the
        trackers ``fit`` (at least 2 of instance g's) onto their current means, in the
        weighted least-squares sense (Procrustes, closed form; weight m = mass wt).  With rest offsets
        p_i = dG0_i - pbar and current offsets q_i = mu_i - qbar about the set's weighted
        centroids pbar (rest, relative to G0) and qbar (current):
            a = sum m p.q,  b = sum m p x q,  D = sum m |p|^2,  s R = [[a, -b], [b, a]] / D
        and G = qbar - s R pbar, the image of the rest centre of mass G0.  D below
        FRAME_MIN_SPREAD times sum m (all of the set's rest points together) gives s R = I;
        the scale sqrt(a^2 + b^2) / D is held to [FRAME_SCALE_MIN, FRAME_SCALE_MAX]."""
        mass, mx, my = self.mass, self.mx, self.my
        w = px = py = qx = qy = 0.0
        for i in fit:                                                # weighted centroids
            m = mass[i] * wt[i]
            w += m
            px += m * self.gdx0[i]
            py += m * self.gdy0[i]
            qx += m * mx[i]
            qy += m * my[i]
        px = px / w
        py = py / w
        qx = qx / w
        qy = qy / w
        a = b = d = 0.0
        for i in fit:
            m = mass[i] * wt[i]
            ux = self.gdx0[i] - px                                   # rest offset p_i
            uy = self.gdy0[i] - py
            vx = mx[i] - qx                                          # current offset q_i
            vy = my[i] - qy
            a += m * (ux * vx + uy * vy)                             # a = sum m p.q
            b += m * (ux * vy - uy * vx)                             # b = sum m p x q
            d += m * (ux * ux + uy * uy)                             # D = sum m |p|^2
        if d <= FRAME_MIN_SPREAD * w:
            c, sn = 1.0, 0.0
        else:
            c = a / d                                                # s R = [[a, -b],
            sn = b / d                                               #        [b, a]] / D
            k2 = c * c + sn * sn                                     # s^2
            if k2 > FRAME_SCALE_MAX * FRAME_SCALE_MAX:
                f = FRAME_SCALE_MAX / math.sqrt(k2)
                c = c * f
                sn = sn * f
            elif k2 < FRAME_SCALE_MIN * FRAME_SCALE_MIN:
                if k2 > 0.0:
                    f = FRAME_SCALE_MIN / math.sqrt(k2)
                    c = c * f
                    sn = sn * f
                else:                                                # no rotation to keep
                    c, sn = FRAME_SCALE_MIN, 0.0
        self.fc[g], self.fs[g] = c, sn
        self.fgx[g] = qx - (c * px - sn * py)                        # G = qbar - s R pbar
        self.fgy[g] = qy - (sn * px + c * py)

    def springs(self) -> None:
        """A spring update of every instance, in order (their clocks left as they are)."""
        for g in range(self.ni):
            self.spring_update(g)

    def spring_update(self, g: int) -> None:
        """Instance g's spring update: its springs and criteria if it is tracking, then
        its state guard."""
        self.n_spring_updates += 1
        t = self.last_t
        if self.state[g] == TRACKING:
            for i in range(self.t0[g], self.t1[g]):                  # eq. (M1): the springs
                lead = self.predict_dt(i, t)                          # act on the means at t
                self.mx[i] = self.mx[i] + self.vx[i] * lead
                self.my[i] = self.my[i] + self.vy[i] * lead
                self.tm[i] = t
            self._springs(g)
        self._guard(g)
        self._spring_box(g)

    def _spring_box(self, g: int) -> None:
        """Instance g's spring box, in whole pixels: the events x, y (integers) within
        SPRING_BOX_PX of the box of its means, [ceil(min) - SPRING_BOX_PX,
        floor(max) + SPRING_BOX_PX] on each axis."""
        xs = self.mx[self.t0[g]:self.t1[g]]
        ys = self.my[self.t0[g]:self.t1[g]]
        self.sbox[g] = (math.ceil(min(xs)) - SPRING_BOX_PX, math.floor(max(xs)) + SPRING_BOX_PX,
                        math.ceil(min(ys)) - SPRING_BOX_PX, math.floor(max(ys)) + SPRING_BOX_PX)

    def in_spring_box(self, g: int, x: int, y: int) -> bool:
        x0, x1, y0, y1 = self.sbox[g]
        return x0 <= x <= x1 and y0 <= y <= y1

    def _guard(self, g: int) -> None:
        """The state guard, after each of instance g's spring updates: a tracker outside
        the position box (springtrack.limits.position_box: one sensor size around the
        sensor), or not finite, is a state no limit-abiding model reaches
        (docs/algorithm.md, Limits); it is counted (``n_resets``) and the instance's whole
        state is reset to the model, never reported."""
        x_lo, x_hi, y_lo, y_hi = self.box
        for i in range(self.t0[g], self.t1[g]):
            if not (x_lo <= self.mx[i] < x_hi and y_lo <= self.my[i] < y_hi):
                self.n_resets += 1
                self._reset_instance(g)
                break

    def _springs(self, g: int) -> None:
        t0, t1, c0, c1 = self.t0[g], self.t1[g], self.c0[g], self.c1[g]
        nc = c1 - c0
        mx, my, im = self.mx, self.my, self.inv_mass
        ddx = {i: 0.0 for i in range(t0, t1)}
        ddy = {i: 0.0 for i in range(t0, t1)}
        e_euc, e_tor, e_car = self.energy
        fc, fs = self.fc[g], self.fs[g]
        need_torsion, car_sim = self.need_torsion[g], self.car_sim[g]
        dth_raw = {}
        mean_dth = 0.0
        if need_torsion:
            for k in range(c0, c1):                                  # eq. (14)
                i, j = self.ca[k], self.cb[k]
                th = math.atan2(my[j] - my[i], mx[j] - mx[i])
                dth_raw[k] = wrap_angle(th - self.th0[k])
                mean_dth += dth_raw[k]
            mean_dth = mean_dth / nc                                 # eq. (15), per instance
        for k in range(c0, c1):
            i, j = self.ca[k], self.cb[k]
            a = self.stiff[k]
            rx = mx[j] - mx[i]
            ry = my[j] - my[i]
            l = math.sqrt(rx * rx + ry * ry)
            dl = l - self.l0[k]                                      # eq. (10)
            e_euc[k] = 0.5 * a * (dl * dl)                           # eq. (12)
            if car_sim:                          # eq. (18), rest offset s R d0 in the frame
                ex = rx - (fc * self.dx0[k] - fs * self.dy0[k])      # of the last update
                ey = ry - (fs * self.dx0[k] + fc * self.dy0[k])
            else:                                                    # eq. (18)
                ex = rx - self.dx0[k]
                ey = ry - self.dy0[k]
            e_car[k] = 0.5 * a * (ex * ex + ey * ey)                 # eq. (20)
            kind = self.kinds[k]
            if kind & EUCLIDEAN:                                     # eq. (11)
                if l > 0.0:
                    inv_l = 1.0 / l
                    cx = rx * inv_l
                    cy = ry * inv_l
                else:
                    cx = math.cos(self.th0[k])
                    cy = math.sin(self.th0[k])
                fx = a * dl * cx
                fy = a * dl * cy
                ddx[i] += fx * im[i]
                ddy[i] += fy * im[i]
                ddx[j] -= fx * im[j]
                ddy[j] -= fy * im[j]
            if need_torsion:
                dth = dth_raw[k] - mean_dth                          # eq. (15)
                e_tor[k] = 0.5 * a * (dth * dth)                     # eq. (17)
                if kind & TORSIONAL:                                 # eq. (16), with
                    eps = a * dth                                    # l cos(th) = rx and
                    cm1 = math.cos(eps) - 1.0                        # l sin(th) = ry:
                    se = math.sin(eps)                               # l (cos(th+eps) - cos th)
                    ux = rx * cm1 - ry * se                          # = rx (cos eps - 1) - ry sin eps
                    uy = ry * cm1 + rx * se
                    ddx[i] += ux * im[i]
                    ddy[i] += uy * im[i]
                    ddx[j] -= ux * im[j]
                    ddy[j] -= uy * im[j]
            else:
                e_tor[k] = 0.0
            if kind & CARTESIAN:                                     # eq. (19)
                ddx[i] += a * ex * im[i]
                ddy[i] += a * ey * im[i]
                ddx[j] -= a * ex * im[j]
                ddy[j] -= a * ey * im[j]
        for i in range(t0, t1):
            mx[i] = mx[i] + ddx[i]
            my[i] = my[i] + ddy[i]
        self._energy_criteria(g)

    def _energy_criteria(self, g: int) -> None:
        t0, t1, c0, c1 = self.t0[g], self.t1[g], self.c0[g], self.c1[g]
        nc = c1 - c0
        if nc == 0:
            return
        e = self.energy[self.ekinds[g]]
        total = 0.0
        for k in range(c0, c1):                                      # eq. (13)
            total += e[k]
        self.mean_energies[g] = total / nc
        thr = self.escale[g] * self.mean_energies[g]
        over_count = {i: 0 for i in range(t0, t1)}
        for k in range(c0, c1):
            if e[k] > thr:
                over_count[self.ca[k]] += 1
                over_count[self.cb[k]] += 1
        a_en = self.egain[g]
        # eq. (22)'s gain: a_en at an over-threshold connection, else a_en times how much
        # the tracker disagrees with the frame (fit_frame)
        gain = {i: a_en if over_count[i] > 0 else 0.0 for i in range(t0, t1)}
        if self.pull_sim[g] or self.car_sim[g]:
            # the frame, fitted to the trackers this update leaves alone, weighted by how
            # well they agree with it; the Cartesian springs use it at the next update
            # (this one's energies decided who is calm)
            for i, dis in self.fit_frame({i: c == 0 for i, c in over_count.items()}, g).items():
                if over_count[i] == 0:
                    gain[i] = a_en * dis
        if self.pull_sim[g]:
            # eq. (22) in the fitted frame: pull toward G + s R dG0 (fit_frame)
            fc, fs, fgx, fgy = self.fc[g], self.fs[g], self.fgx[g], self.fgy[g]
            for i in range(t0, t1):
                if gain[i] > 0.0:
                    tx = fgx + (fc * self.gdx0[i] - fs * self.gdy0[i])
                    ty = fgy + (fs * self.gdx0[i] + fc * self.gdy0[i])
                    self.mx[i] = self.mx[i] + gain[i] * (tx - self.mx[i])
                    self.my[i] = self.my[i] + gain[i] * (ty - self.my[i])
        else:
            # eq. (22): pull both ends of an over-threshold connection toward G + dG0, G the
            # instance's centre of mass after the spring step
            msum = 0.0
            gx = 0.0
            gy = 0.0
            for i in range(t0, t1):
                msum += self.mass[i]
                gx += self.mass[i] * self.mx[i]
                gy += self.mass[i] * self.my[i]
            gx = gx / msum
            gy = gy / msum
            for i in range(t0, t1):
                if gain[i] > 0.0:
                    self.mx[i] = self.mx[i] + gain[i] * (gx + self.gdx0[i] - self.mx[i])
                    self.my[i] = self.my[i] + gain[i] * (gy + self.gdy0[i] - self.my[i])
        if self.tau_m > 0.0:
            self._pull_velocities(g, over_count)
        if self.c_h > 0.0:
            # eq. (M9): the half offset of a tracker eq. (22) pulls goes toward 0 by the
            # same gain, h = h - gain h: a pull says the tracker's events were not its
            # part's, and so were not its part's edges either
            for i in range(t0, t1):
                if gain[i] > 0.0:
                    self.hx[i] = self.hx[i] - gain[i] * self.hx[i]
                    self.hy[i] = self.hy[i] - gain[i] * self.hy[i]
        for i in range(t0, t1):
            # eq. (21): insensitive while every connection of the tracker is over
            self.sensitive[i] = not (self.degree[i] > 0 and over_count[i] == self.degree[i])

    def _pull_velocities(self, g: int, over_count: dict) -> None:
        """eq. (M8), this project's: the velocity of a tracker eq. (22) pulls moves toward
        the mass-weighted mean velocity of its instance's trackers left alone (0 if none),
        by the same gain: a tracker pulled back to the structure moves with it, not on
        with what it followed (an occluder's edge, say)."""
        w = vx = vy = 0.0
        for i in range(self.t0[g], self.t1[g]):
            if over_count[i] == 0:
                w += self.mass[i]
                vx += self.mass[i] * self.vx[i]
                vy += self.mass[i] * self.vy[i]
        if w > 0.0:
            vx = vx / w
            vy = vy / w
        a = self.egain[g]
        for i in range(self.t0[g], self.t1[g]):
            if over_count[i] > 0:
                self.vx[i] = self.vx[i] + a * (vx - self.vx[i])
                self.vy[i] = self.vy[i] + a * (vy - self.vy[i])

    # ---- instances' states ------------------------------------------------------
    def set_state(self, g: int, state: int) -> None:
        """Instance g's state; a tracking instance's trackers are sensitive, the others'
        are not (the next spring update decides eq. 21 again)."""
        self.state[g] = int(state)
        for i in range(self.t0[g], self.t1[g]):
            self.sensitive[i] = state == TRACKING

    def place(self, g: int, model: ShapeModel) -> None:
        """Instance g placed as ``model`` (its model moved, e.g. by an acquisition: the
        same trackers and connections): positions, covariances and the rest geometry of
        eqs. (10), (14), (18), (22) from it (and the state the guard resets it to),
        activities 0, the frame at rest; tracking."""
        arr = self._load_rest(g, model)
        for j in range(len(arr["x"])):
            i = self.t0[g] + j
            self.mx[i], self.my[i] = float(arr["x"][j]), float(arr["y"][j])
            self.sxx[i], self.sxy[i] = float(arr["sxx"][j]), float(arr["sxy"][j])
            self.syy[i] = float(arr["syy"][j])
            self.act[i] = 0.0
            self.tlast[i] = 0
            self._still(i)
            self._clamp_and_invert(i)
        self._rest_frame(g)
        self.set_state(g, TRACKING)

    def relocate(self, g: int, idx, x, y, sxx, sxy, syy) -> None:
        """Instance g's trackers ``idx`` (indices within the instance) put at means (x, y)
        with covariances (sxx, sxy, syy) (one value each per index; clamped as eq. (4)'s),
        their activities 0 (eq. 6: no event of theirs yet where they now are) and their
        motion state as placed (``_still``: eqs. M1-M9 start again); every other
        tracker, the rest geometry, the frame and the state kept."""
        for k, j in enumerate(idx):
            i = self.t0[g] + int(j)
            if not self.t0[g] <= i < self.t1[g]:
                raise IndexError(f"relocate: tracker {int(j)} is not in instance {g}")
            self.mx[i], self.my[i] = float(x[k]), float(y[k])
            self.sxx[i], self.sxy[i], self.syy[i] = float(sxx[k]), float(sxy[k]), float(syy[k])
            self.act[i] = 0.0
            self.tlast[i] = 0
            self._still(i)
            self._clamp_and_invert(i)

    def move(self, g: int, sim: tuple, model: ShapeModel) -> None:
        """Instance g moved rigidly by the similarity ``sim`` = (a, b, tx, ty), x -> A x + t
        with A = s R = [[a, -b], [b, a]], keeping its activities, sensitivities, state and
        deformation: each mean mapped, mu' = A mu + t; each covariance turned and scaled,
        Sigma' = A Sigma A^T = s^2 R Sigma R^T (then clamped as eq. (4)'s are); the
        similarity frame's centre mapped (2-D similarities commute, so its s R is kept);
        the rest geometry (the state guard's means and covariances, eqs. (10), (14), (18),
        (22)'s rest terms) from ``model``, the instance's model moved by the same ``sim``."""
        a, b, tx, ty = (float(v) for v in sim)
        self._load_rest(g, model)
        for i in range(self.t0[g], self.t1[g]):
            x, y = self.mx[i], self.my[i]
            self.mx[i] = a * x - b * y + tx                          # mu' = A mu + t
            self.my[i] = b * x + a * y + ty
            vx, vy = self.vx[i], self.vy[i]                          # v' = A v, h' = A h
            self.vx[i] = min(max(a * vx - b * vy, -VELOCITY_MAX), VELOCITY_MAX)
            self.vy[i] = min(max(b * vx + a * vy, -VELOCITY_MAX), VELOCITY_MAX)
            hx, hy, hmax = self.hx[i], self.hy[i], self.h_max
            self.hx[i] = min(max(a * hx - b * hy, -hmax), hmax)
            self.hy[i] = min(max(b * hx + a * hy, -hmax), hmax)
            sxx, sxy, syy = self.sxx[i], self.sxy[i], self.syy[i]
            # Sigma' = A Sigma A^T
            pxx, pxy = a * sxx - b * sxy, a * sxy - b * syy          # rows of A Sigma
            pyx, pyy = b * sxx + a * sxy, b * sxy + a * syy
            self.sxx[i] = pxx * a - pxy * b
            self.sxy[i] = pxx * b + pxy * a
            self.syy[i] = pyx * b + pyy * a
            self._clamp_and_invert(i)
        gx, gy = self.fgx[g], self.fgy[g]
        self.fgx[g] = a * gx - b * gy + tx
        self.fgy[g] = b * gx + a * gy + ty

    def _load_rest(self, g: int, model: ShapeModel):
        """Instance g's rest geometry from ``model`` (the same trackers and connections):
        the means and covariances the state guard resets to, the offsets to the rest centre
        of mass, the connections' rest lengths, angles and offsets.  Returns its arrays."""
        self.mset = self.mset.replaced(g, model)
        arr = model.arrays()
        t0, c0 = self.t0[g], self.c0[g]
        for j in range(len(arr["x"])):
            i = t0 + j
            for rest, key in zip(self.rest, ("x", "y", "sxx", "sxy", "syy")):
                rest[i] = float(arr[key][j])          # the state guard resets to this
            self.gdx0[i], self.gdy0[i] = float(arr["gdx0"][j]), float(arr["gdy0"][j])
        for j in range(len(arr["l0"])):
            k = c0 + j
            self.l0[k], self.th0[k] = float(arr["l0"][j]), float(arr["th0"][j])
            self.dx0[k], self.dy0[k] = float(arr["dx0"][j]), float(arr["dy0"][j])
        return arr

    # ---- observation -----------------------------------------------------------
    def frame(self, g: int = 0) -> tuple:
        """Instance g's similarity frame of the last spring update (fit_frame): (c, sn, gx,
        gy) with s R = [[c, -sn], [sn, c]] and (gx, gy) the image of the rest centre of
        mass; (1, 0, G0) until a spring update fits one."""
        return (self.fc[g], self.fs[g], self.fgx[g], self.fgy[g])

    def activity_at(self, i: int, t: int) -> float:
        """eq. (6) evaluated lazily at time t (no event)."""
        return self.act[i] * math.exp(-(t - self.tlast[i]) / self.tau)

    def snapshot(self, t: int) -> tuple:
        """(x, y, sxx, sxy, syy, activity, vx, vy, active, sensitive, state) lists at
        event time t (springtrack.track.TRACK_FIELDS): the means predicted to t (eq. M1),
        the velocities in px/s."""
        act = [self.activity_at(i, t) for i in range(self.n)]
        thr = self.act_thr
        lead = [self.predict_dt(i, t) for i in range(self.n)]
        return ([self.mx[i] + self.vx[i] * lead[i] for i in range(self.n)],
                [self.my[i] + self.vy[i] * lead[i] for i in range(self.n)],
                list(self.sxx), list(self.sxy), list(self.syy),
                act, [v * 1e6 for v in self.vx], [v * 1e6 for v in self.vy],
                [a > thr for a in act], list(self.sensitive),
                [self.state[g] for g in self.inst])

    def run(self, events: np.ndarray, sample_us: int | None = None):
        """Process an event array; with ``sample_us``, return [(t_us, snapshot), ...] taken at
        the multiples of sample_us the sampling rule of springtrack.sampling names, each the
        state after all events with t < t_us."""
        samples = []
        next_t = UNSET
        for t, x, y, p in zip(events["t"].tolist(), events["x"].tolist(), events["y"].tolist(),
                              events["p"].tolist()):
            if sample_us:
                if next_t == UNSET:
                    next_t = first_sample_time(t, sample_us)
                if sample_due(t, next_t, self.last_t):
                    while True:
                        next_t = next_sample(t, next_t, self.last_t, sample_us)
                        if t < next_t:
                            break
                        samples.append((next_t, self.snapshot(next_t)))
                        next_t += sample_us
            self.step(t, x, y, p)
        return samples
