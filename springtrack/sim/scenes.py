"""Scenes for the simulated ATIS sensor, with exact ground truth.

A scene is a deterministic function of time (and of its seed) giving

* ``frame(t_s)`` -> :class:`Frame`: what the sensor sees -- additive bright blobs on a
  flat background (rows ``x, y, sxx, sxy, syy, amplitude, edge``; covariance in px^2;
  edge 0 = Gaussian, edge > 0 = flat disk of Mahalanobis radius sqrt(2) with a logistic
  edge of that sharpness) and opaque soft-edged ellipses drawn on top of them (rows
  ``x, y, sxx, sxy, syy, intensity, edge``), in linear intensity units;

The parts of the paper scenes are disks: a moving disk fires events on its rim, a ring
whose covariance is the part's covariance, so the event cloud matches the preset
tracker's initial covariance (a Gaussian's log response would put most events in its
far tails, ~2-3 sigma out, beyond the tracker's gate).
* ``truth(t_s)`` -> ``(K, 2)``: the true image position of each part's centre, in the
  order of ``part_ids`` (the tracker ids of the matching preset of
  :mod:`springtrack.model`);
* ``initial_model()``: the preset model placed where the scene starts (the paper
  initialises the trackers from the gray-level snapshot).

Scenes of paper section IV (all start at rest pose, so the initial model is exact):

``grid_rot_y``     IV-A first experiment (Figs. 9-11): 3x3 grid on a screen rotating about
                   the vertical axis between -75 and +75 deg at 15 deg/s, plus vertical motion.
``grid_pull``      IV-A second experiment (Figs. 12-14): rotation about x (+-30 deg, 15 deg/s)
                   and y (+-45 deg, 10 deg/s), horizontal and vertical motion, random
                   disturbances; one element (``PULLED``) is pulled ~60 px away and returned
                   in every 10 s cycle.  Its truth is where it would be without the pull.
``grid_inplane``   Fig. 16: in-plane rotation between +45 and -45 deg (15 deg/s) while
                   translating.

Scenes beyond the paper, for the similarity frame (``pull_frame``, ``cartesian_frame``):

``grid_spin``      in-plane rotation between +90 and -90 deg (15 deg/s) while translating.
``grid_scale``     the grid scaling between 0.7 and 1.3 times its size (0.06 per s: a
                   screen approaching and receding) while translating.
``face_occlusion`` IV-B (Figs. 17-21): the 26 parts of ``face26`` as bright blobs, the face
                   moving, approaching (scale) and rolling; a hand (palm + 4 fingers, opaque,
                   covering the lower or middle part of the face: a partial occlusion)
                   sweeps across the face 3 times in 20 s (every 6 s, 2.4 s per pass).

``moving_blob``    a single blob translating horizontally (``speed`` px/s, ``amplitude``,
                   ``sigma``, ``edge``: 0 Gaussian (default), > 0 disk), for the sensor's
                   statistical tests.

The grid lies on a screen viewed by a pinhole camera (focal length = screen distance
``D``, so the rest pose is 1:1 in pixels); a blob's image covariance is
``sigma^2 J J^T`` with ``J`` the Jacobian of the projection at its centre.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from springtrack.model import FACE_INTERNAL, ShapeModel, face26, face_layout, grid3x3

WIDTH, HEIGHT = 304, 240
CX, CY = 152.0, 120.0


@dataclass
class Frame:
    blobs: np.ndarray        # (n, 7) x, y, sxx, sxy, syy, amplitude, edge (0: Gaussian)
    occluders: np.ndarray    # (m, 7) x, y, sxx, sxy, syy, intensity, edge


NO_OCCLUDERS = np.zeros((0, 7))


def triangle(t, lo: float, hi: float, speed: float):
    """Angle sweeping 0 -> hi -> lo -> hi ... at constant ``speed`` (units/s), starting at 0."""
    span = hi - lo
    s = (t * speed - lo) % (2.0 * span)      # phase: value 0 at t = 0, rising
    return lo + (s if s <= span else 2.0 * span - s)


def smooth_step(u):
    """0 for u <= 0, 1 for u >= 1, C1 raised cosine in between."""
    u = min(max(u, 0.0), 1.0)
    return 0.5 - 0.5 * math.cos(math.pi * u)


class Scene:
    name = "scene"
    preset = None              # name of the springtrack.model preset, or None
    part_ids: list[str] = []
    default_seconds = 10.0
    background = 0.15

    def __init__(self, seed: int = 0):
        self.seed = int(seed)

    def frame(self, t: float) -> Frame:
        raise NotImplementedError

    def truth(self, t: float) -> np.ndarray:
        raise NotImplementedError

    def initial_model(self, **kw) -> ShapeModel:
        raise ValueError(f"scene {self.name!r} has no matching shape model")


# ---- moving_blob: one blob, for the sensor tests -------------------------------------
class MovingBlob(Scene):
    name = "moving_blob"
    part_ids = ["blob"]
    default_seconds = 1.0

    def __init__(self, seed=0, speed=40.0, amplitude=1.0, sigma=4.0, x0=60.0, y0=CY, edge=0.0):
        super().__init__(seed)
        self.edge = float(edge)
        self.speed, self.amplitude, self.sigma = float(speed), float(amplitude), float(sigma)
        self.x0, self.y0 = float(x0), float(y0)

    def truth(self, t):
        return np.array([[self.x0 + self.speed * t, self.y0]])

    def frame(self, t):
        (x, y), = self.truth(t)
        s2 = self.sigma ** 2
        return Frame(np.array([[x, y, s2, 0.0, s2, self.amplitude, self.edge]]), NO_OCCLUDERS)


# ---- grids on a screen ------------------------------------------------------------------
def _rot(ax: float, ay: float, az: float) -> np.ndarray:
    """R = Rz(az) Ry(ay) Rx(ax), angles in radians."""
    cx, sx, cy, sy, cz, sz = (math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay),
                              math.cos(az), math.sin(az))
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


class GridScene(Scene):
    """3x3 grid of blobs (ids r{row}c{col}) on a screen: subclasses give the pose."""
    preset = "grid3x3"
    part_ids = [f"r{r}c{c}" for r in range(3) for c in range(3)]
    default_seconds = 20.0
    D = 400.0                    # screen distance = focal length, px

    def __init__(self, seed=0, spacing=50.0, sigma=5.0, amplitude=1.0, cx=CX, cy=CY):
        super().__init__(seed)
        self.spacing, self.sigma, self.amplitude = float(spacing), float(sigma), float(amplitude)
        self.cx, self.cy = float(cx), float(cy)
        g = np.array([[(c - 1) * spacing, (r - 1) * spacing] for r in range(3) for c in range(3)])
        self.screen = g          # (9, 2) screen coordinates about the grid centre

    def pose(self, t):
        """(angle_x, angle_y, angle_z) in radians and image offset (dx, dy) in px."""
        raise NotImplementedError

    def element_offset(self, t) -> np.ndarray:
        """(9, 2) image-plane displacement of individual elements (not in the truth)."""
        return np.zeros((9, 2))

    def zoom(self, t) -> float:
        """Image scale about the grid centre (1: the rest size), as if the screen moved
        along the optical axis."""
        return 1.0

    def _project(self, t):
        ax, ay, az, dx, dy = self.pose(t)
        R = _rot(ax, ay, az)
        P = self.screen @ R[:, :2].T              # (9, 3) camera coordinates minus (0,0,D)
        Z = self.D + P[:, 2]
        f = self.D * self.zoom(t)
        u = self.cx + dx + f * P[:, 0] / Z
        v = self.cy + dy + f * P[:, 1] / Z
        # Jacobian of (u, v) wrt screen (X, Y): d(fPx/Z)/dX = f (R00 Z - Px R20) / Z^2 ...
        J = np.empty((9, 2, 2))
        for i, (row_img, row) in enumerate(((P[:, 0], 0), (P[:, 1], 1))):
            for j in range(2):
                J[:, i, j] = f * (R[row, j] * Z - row_img * R[2, j]) / Z ** 2
        return np.stack([u, v], axis=1), J

    def truth(self, t):
        return self._project(t)[0]

    def frame(self, t):
        uv, J = self._project(t)
        uv = uv + self.element_offset(t)
        C = self.sigma ** 2 * np.einsum("kij,klj->kil", J, J)
        blobs = np.column_stack([uv, C[:, 0, 0], C[:, 0, 1], C[:, 1, 1],
                                 np.full(9, self.amplitude), np.full(9, 3.0 * self.sigma)])
        return Frame(blobs, NO_OCCLUDERS)

    def initial_model(self, **kw):
        """grid3x3 at the rest pose; ``kw`` (stiffness, springs) go to the preset."""
        return grid3x3(self.cx, self.cy, self.spacing, sigma_px=self.sigma, **kw)


class GridRotY(GridScene):
    name = "grid_rot_y"

    def pose(self, t):
        ay = math.radians((triangle(t, -75.0, 75.0, 15.0)))
        return 0.0, ay, 0.0, 0.0, 25.0 * math.sin(2 * math.pi * t / 5.0)


class GridPull(GridScene):
    name = "grid_pull"
    PULLED = "r0c2"
    PULL_PX = 60.0
    CYCLE_S = 10.0
    # within each cycle: ramp out over [3, 4.5] s, hold, ramp back over [6.5, 8] s
    PULL_TIMES = (3.0, 4.5, 6.5, 8.0)

    def __init__(self, seed=0, **kw):
        super().__init__(seed, **kw)
        rng = np.random.default_rng([self.seed, 5])
        # random disturbances: 3 sinusoids per axis, 0.5-2 Hz, 1.5 px each, zero at t=0
        self.dist_f = rng.uniform(0.5, 2.0, size=(2, 3))
        self.dist_a = np.full((2, 3), 1.5)
        self.pull_dir = np.array([1.0, -1.0]) / math.sqrt(2.0)    # away from the grid centre
        self.k_pulled = self.part_ids.index(self.PULLED)

    def pose(self, t):
        ax = math.radians((triangle(t, -30.0, 30.0, 15.0)))
        ay = math.radians((triangle(t, -45.0, 45.0, 10.0)))
        dist = (self.dist_a * np.sin(2 * math.pi * self.dist_f * t)).sum(axis=1)
        dx = 20.0 * math.sin(2 * math.pi * t / 7.0) + dist[0]
        dy = 15.0 * math.sin(2 * math.pi * t / 5.0) + dist[1]
        return ax, ay, 0.0, dx, dy

    def pull_amount(self, t) -> float:
        a, b, c, d = self.PULL_TIMES
        u = t % self.CYCLE_S
        return smooth_step((u - a) / (b - a)) * (1.0 - smooth_step((u - c) / (d - c)))

    def element_offset(self, t):
        off = np.zeros((9, 2))
        off[self.k_pulled] = self.PULL_PX * self.pull_amount(t) * self.pull_dir
        return off


class GridInplane(GridScene):
    """In-plane rotation 0 -> +amplitude -> -amplitude ... (deg, at speed deg/s) while
    translating."""
    name = "grid_inplane"
    amplitude_deg = 45.0

    def __init__(self, seed=0, amplitude_deg=None, speed_deg_s=15.0, **kw):
        super().__init__(seed, **kw)
        if amplitude_deg is not None:
            self.amplitude_deg = float(amplitude_deg)
        self.speed_deg_s = float(speed_deg_s)

    def pose(self, t):
        a = self.amplitude_deg
        az = math.radians((triangle(t, -a, a, self.speed_deg_s)))
        return (0.0, 0.0, az, 30.0 * math.sin(2 * math.pi * t / 8.0),
                20.0 * math.sin(2 * math.pi * t / 6.0))


class GridSpin(GridInplane):
    name = "grid_spin"
    amplitude_deg = 90.0


class GridScale(GridScene):
    """The grid scaling 1 -> 1 + amplitude -> 1 - amplitude ... (speed per s) while
    translating."""
    name = "grid_scale"

    def __init__(self, seed=0, amplitude=0.3, speed=0.06, **kw):
        super().__init__(seed, **kw)
        self.amplitude, self.speed = float(amplitude), float(speed)

    def zoom(self, t):
        return 1.0 + triangle(t, -self.amplitude, self.amplitude, self.speed)

    def pose(self, t):
        return (0.0, 0.0, 0.0, 30.0 * math.sin(2 * math.pi * t / 8.0),
                20.0 * math.sin(2 * math.pi * t / 6.0))


# ---- face with a hand ------------------------------------------------------------------
class FaceOcclusion(Scene):
    """face26 parts as bright blobs; the face translates, scales 120 -> 144 px and rolls
    +-12 deg; a hand sweeps across it in 2.4 s every ``hand_period`` s from t = 4 s."""
    name = "face_occlusion"
    preset = "face26"
    part_ids = list(face_layout())
    default_seconds = 20.0
    internal = list(FACE_INTERNAL)

    def __init__(self, seed=0, scale=120.0, cx=CX, cy=CY, amplitude=2.0, outline_amplitude=1.5,
                 hand_period=6.0, hand_first=4.0, hand_duration=2.4, hand_intensity=0.3,
                 hand_size=0.16, hand_rows=(0.35, 0.2, 0.35), motion=1.0):
        super().__init__(seed)
        self.scale0, self.cx0, self.cy0 = float(scale), float(cx), float(cy)
        lay = face_layout()
        self.layout = np.array([lay[k][:2] for k in self.part_ids])         # (26, 2)
        self.sig = np.array([lay[k][2:] for k in self.part_ids])            # (26, 2)
        amp = [amplitude if k in FACE_INTERNAL else outline_amplitude for k in self.part_ids]
        self.amp = np.array(amp, dtype=float)
        self.edge_k = 3.0 * self.sig.min(axis=1)      # x face height = disk edge sharpness
        self.hand_period, self.hand_first = float(hand_period), float(hand_first)
        self.hand_duration, self.hand_intensity = float(hand_duration), float(hand_intensity)
        self.hand_size, self.hand_rows = float(hand_size), tuple(hand_rows)
        self.motion = float(motion)
        rng = np.random.default_rng([self.seed, 7])
        self.phase = rng.uniform(0, 2 * math.pi, size=4)

    def pose(self, t):
        """centre (x, y), face height (px), roll (rad); rest pose at t = 0."""
        m, ph = self.motion, self.phase
        x = self.cx0 + m * (25.0 * math.sin(2 * math.pi * t / 6.0)
                            + 8.0 * (math.sin(2 * math.pi * t / 1.7 + ph[0]) - math.sin(ph[0])))
        y = self.cy0 + m * (12.0 * math.sin(2 * math.pi * t / 5.0)
                            + 5.0 * (math.sin(2 * math.pi * t / 1.3 + ph[1]) - math.sin(ph[1])))
        scale = self.scale0 * (1.0 + m * 0.1 * (1.0 - math.cos(2 * math.pi * t / 16.0)))
        roll = m * math.radians(12.0) * math.sin(2 * math.pi * t / 4.0)
        return x, y, scale, roll

    def truth(self, t):
        x, y, s, roll = self.pose(t)
        c, sn = math.cos(roll), math.sin(roll)
        lx, ly = self.layout[:, 0] * s, self.layout[:, 1] * s
        return np.column_stack([x + c * lx - sn * ly, y + sn * lx + c * ly])

    def hand(self, t):
        """Occluder rows of the hand, or an empty array when no pass is under way."""
        if t < self.hand_first:
            return NO_OCCLUDERS
        k, u = divmod(t - self.hand_first, self.hand_period)
        if u > self.hand_duration:
            return NO_OCCLUDERS
        x, y, s, _ = self.pose(t)
        direction = 1.0 if int(k) % 2 == 0 else -1.0
        span = WIDTH + 2 * 0.9 * s
        hx = (-0.9 * s + span * u / self.hand_duration)
        hx = hx if direction > 0 else WIDTH - hx
        pr = self.hand_size * s                             # palm radius
        hy = y + self.hand_rows[int(k) % len(self.hand_rows)] * s   # palm centre
        rows = [[hx, hy, pr ** 2, 0.0, (1.2 * pr) ** 2]]
        for j, fx in enumerate((-0.6, -0.2, 0.2, 0.6)):      # four fingers above the palm
            fl = (0.85 if j in (1, 2) else 0.7) * pr
            rows.append([hx + fx * pr, hy - 1.1 * pr - 0.6 * fl, (0.22 * pr) ** 2, 0.0, fl ** 2])
        occ = np.array(rows)
        return np.column_stack([occ, np.full(len(occ), self.hand_intensity),
                                np.full(len(occ), 24.0)])

    def frame(self, t):
        x, y, s, roll = self.pose(t)
        xy = self.truth(t)
        c, sn = math.cos(roll), math.sin(roll)
        vx, vy = (s * self.sig[:, 0]) ** 2, (s * self.sig[:, 1]) ** 2
        # R diag(vx, vy) R^T
        sxx = c * c * vx + sn * sn * vy
        syy = sn * sn * vx + c * c * vy
        sxy = c * sn * (vx - vy)
        blobs = np.column_stack([xy, sxx, sxy, syy, self.amp, s * self.edge_k])
        return Frame(blobs, self.hand(t))

    def initial_model(self, **kw):
        """face26 at the rest pose; ``kw`` (stiffness) go to the preset."""
        return face26(self.cx0, self.cy0, self.scale0, **kw)


# ---- any scene placed elsewhere -----------------------------------------------------
class Placed(Scene):
    """Another scene seen through a similarity about the sensor centre: rotated by
    ``angle_deg`` (clockwise on screen, image y pointing down), scaled by ``scale``, then
    shifted by (``dx``, ``dy``) px -- for acquisition from any start pose.  ``freeze``
    keeps the base scene at its t = 0 frame (a static object); ``jitter_px`` moves the
    whole image on a circle of that radius at ``jitter_hz`` (zero at t = 0), as a camera
    on a vibrating mount or a fixating eye does, so that a static object still fires
    events.  Blob and occluder edges keep their sharpness in px."""

    def __init__(self, base: Scene, angle_deg=0.0, scale=1.0, dx=0.0, dy=0.0, freeze=False,
                 jitter_px=0.0, jitter_hz=8.0):
        super().__init__(base.seed)
        if not scale > 0:
            raise ValueError(f"Placed: scale must be positive, got {scale}")
        self.base = base
        self.name = f"{base.name}+placed"
        self.preset, self.part_ids = base.preset, base.part_ids
        self.default_seconds, self.background = base.default_seconds, base.background
        th = math.radians(angle_deg)
        self.rot = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        self.scale, self.shift = float(scale), np.array([dx, dy], float)
        self.freeze, self.jitter_px, self.jitter_hz = bool(freeze), float(jitter_px), float(jitter_hz)
        self.centre = np.array([CX, CY])

    def _t(self, t):
        return 0.0 if self.freeze else t

    def _offset(self, t):
        w = 2 * math.pi * self.jitter_hz * t
        return self.shift + self.jitter_px * np.array([math.sin(w), 1.0 - math.cos(w)])

    def _points(self, xy, t):
        return self.centre + self.scale * (xy - self.centre) @ self.rot.T + self._offset(t)

    def _rows(self, rows, t):
        """Transform rows (x, y, sxx, sxy, syy, value, edge)."""
        if not len(rows):
            return rows
        out = rows.copy()
        out[:, :2] = self._points(rows[:, :2], t)
        cov = np.stack([np.stack([rows[:, 2], rows[:, 3]], -1),
                        np.stack([rows[:, 3], rows[:, 4]], -1)], -2)
        cov = self.scale ** 2 * (self.rot @ cov @ self.rot.T)
        out[:, 2], out[:, 3], out[:, 4] = cov[:, 0, 0], cov[:, 0, 1], cov[:, 1, 1]
        out[:, 6] = rows[:, 6] * self.scale          # edge sharpness is in sigma units
        return out

    def truth(self, t):
        return self._points(self.base.truth(self._t(t)), t)

    def frame(self, t):
        f = self.base.frame(self._t(t))
        return Frame(self._rows(f.blobs, t), self._rows(f.occluders, t))

    def initial_model(self, **kw):
        """The base scene's initial model, placed as the scene is at t = 0."""
        from springtrack.acquisition.acquire import fit_pose, place
        model = self.base.initial_model(**kw)
        xy = self.truth(0.0)
        return place(model, fit_pose(model, xy[:, 0], xy[:, 1]))


# ---- losing the object: a jump, a full occlusion, an exit and return ---------------
class Disrupted(Scene):
    """Another scene disrupted, to test loss and re-acquisition: from ``at_s`` on, the
    object is shifted by (``dx``, ``dy``) px (a jump: ``move_s`` 0), reached along a
    straight line in ``move_s`` s; with ``back_s`` it returns to its own place, again in
    ``move_s`` s, starting at ``back_s`` (an exit and return: shift it off the sensor);
    ``hide_s`` = (start, end): the object is not seen at all in between (a full
    occlusion: no blob drawn, no event fired).  :meth:`returned` gives the time the
    object is whole and in view again."""

    def __init__(self, base: Scene, at_s=None, dx=0.0, dy=0.0, move_s=0.0, back_s=None,
                 hide_s=None):
        super().__init__(base.seed)
        self.base = base
        self.name = f"{base.name}+disrupted"
        self.preset, self.part_ids = base.preset, base.part_ids
        self.default_seconds, self.background = base.default_seconds, base.background
        self.at_s, self.shift, self.move_s = at_s, np.array([dx, dy], float), float(move_s)
        self.back_s, self.hide_s = back_s, hide_s

    def _offset(self, t):
        if self.at_s is None or t < self.at_s:
            return np.zeros(2)
        u = 1.0 if self.move_s <= 0 else min((t - self.at_s) / self.move_s, 1.0)
        if self.back_s is not None and t >= self.back_s:
            u = 0.0 if self.move_s <= 0 else max(1.0 - (t - self.back_s) / self.move_s, 0.0)
        return u * self.shift

    def returned(self) -> float:
        """When the object is in view at its place again (s): after the occlusion, the
        jump or the return."""
        if self.hide_s is not None:
            return float(self.hide_s[1])
        if self.back_s is not None:
            return float(self.back_s + self.move_s)
        return float(self.at_s + self.move_s)

    def truth(self, t):
        return self.base.truth(t) + self._offset(t)

    def frame(self, t):
        f = self.base.frame(t)
        if self.hide_s is not None and self.hide_s[0] <= t < self.hide_s[1]:
            return Frame(f.blobs[:0], f.occluders)
        off = self._offset(t)
        blobs, occ = f.blobs.copy(), f.occluders.copy()
        blobs[:, :2] += off
        occ[:, :2] += off
        return Frame(blobs, occ)

    def initial_model(self, **kw):
        return self.base.initial_model(**kw)


# ---- several objects in one view -----------------------------------------------------
class Together(Scene):
    """Several scenes seen at once: their blobs and occluders drawn together (later
    scenes on top); the truth is each scene's in turn, ``parts`` the slices of each."""

    def __init__(self, *scenes):
        super().__init__(scenes[0].seed)
        self.scenes = list(scenes)
        self.name = "+".join(sc.name for sc in scenes)
        self.part_ids = [p for sc in scenes for p in sc.part_ids]
        self.default_seconds = min(sc.default_seconds for sc in scenes)
        self.background = scenes[0].background
        bounds = np.cumsum([0] + [len(sc.part_ids) for sc in scenes])
        self.parts = [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:])]

    def truth(self, t):
        return np.concatenate([sc.truth(t) for sc in self.scenes])

    def frame(self, t):
        fs = [sc.frame(t) for sc in self.scenes]
        return Frame(np.concatenate([f.blobs for f in fs]),
                     np.concatenate([f.occluders for f in fs]))

    def initial_models(self, **kw) -> list:
        return [sc.initial_model(**kw) for sc in self.scenes]


SCENES: dict[str, type[Scene]] = {cls.name: cls for cls in
                                   (GridRotY, GridPull, GridInplane, GridSpin, GridScale,
                                    FaceOcclusion, MovingBlob)}


def make_scene(name: str, seed: int = 0, **params) -> Scene:
    """Instantiate a scene of :data:`SCENES` by name; unknown names raise ValueError."""
    if isinstance(name, Scene):
        return name
    if name not in SCENES:
        raise ValueError(f"unknown scene {name!r}; known: {', '.join(SCENES)}")
    return SCENES[name](seed=seed, **params)
