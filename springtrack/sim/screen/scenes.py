"""The screen generator's scenes: dark parts on a bright screen (or a face before a dark
wall), each a deterministic function of time and seed, with exact ground truth.

A scene gives ``shapes(t_s)`` (rows of :mod:`.render`, painted in order), ``background``,
``truth(t_s)`` -> (K, 2) the true image position of each part's centre in the order of
``part_ids`` (the matching preset's tracker ids), and ``initial_model()``.  The parts are
discs (ellipses) whose rim fires the events, so the matching tracker's covariance is that
of the rim: a disc of radius r has sigma = r / sqrt(2).

``grid_pull``      3x3 dark discs (spacing 45 px, radius 10 px) on a screen rotating about x
                   (+-30 deg at 15 deg/s) and y (+-45 deg at 10 deg/s) while drifting,
                   with a smooth ~1.5 px jitter; disc ``r1c2`` is pulled out along the
                   grid's X axis by up to 1.5 spacings in every 8 s cycle (out over 1.5 s
                   from 2 s, held 2 s, back over 1.5 s).  Its truth is where it would be
                   without the pull.
``grid_inplane``   the grid turning in its plane between +-45 deg (15 deg/s) while drifting.
``grid_rot_y``     the grid turning about the vertical axis between +-60 deg (15 deg/s)
                   while moving up and down.
``face_occlusion`` a bright face (an ellipse: its rim carries the 19 outline parts) with
                   dark brows, eyes, nostrils and mouth (the 7 internal parts of face26)
                   before a dark wall, moving, rolling and approaching; a hand (palm,
                   four fingers, thumb; opaque) sweeps across its lower half 3 times.
``shapes_handheld`` eight dark shapes (discs, a ring, ellipses, a bar, a pair) on a bright
                   wall filmed by a hand-held camera (shift, roll, zoom; ``speed`` px/s
                   RMS); ``transform(t)`` gives the whole image motion, the truth of a
                   learned model's trackers wherever they sit.
``dots``           a dark and a bright disc (ids ``dark``, ``bright``) going back and forth
                   along rows y = 80 and 160 at ``speed`` px/s (radius ``radius`` px) on a
                   mid-grey screen; for fast-motion and learning tests.
"""
from __future__ import annotations

import math

import numpy as np

from springtrack.model import (FACE_OUTLINE_RADII, ShapeModel, TrackerSpec, face26,
                               face_layout, grid3x3)

from ..scenes import _rot as _rotation
from .render import shape

WIDTH, HEIGHT = 304, 240
CX, CY = 152.0, 120.0
RIM_SIGMA = 1.0 / math.sqrt(2.0)       # rim covariance of a unit disc: r^2 / 2 per axis


def tri(t, amp, speed):
    """0 -> amp -> -amp -> amp ... at ``speed`` units/s (a triangle wave starting at 0)."""
    if amp <= 0:
        return 0.0
    s = (t * speed + amp) % (4.0 * amp)
    return (s if s <= 2.0 * amp else 4.0 * amp - s) - amp


def ramp(u):
    """Smoothstep 3u^2 - 2u^3 on [0, 1], 0 before and 1 after."""
    u = min(max(u, 0.0), 1.0)
    return u * u * (3.0 - 2.0 * u)


class ScreenScene:
    name = "scene"
    part_ids: list[str] = []
    default_seconds = 10.0
    background = 1.0

    def __init__(self, seed: int = 0):
        self.seed = int(seed)

    def shapes(self, t: float) -> np.ndarray:
        raise NotImplementedError

    def truth(self, t: float) -> np.ndarray:
        raise NotImplementedError

    def initial_model(self, **kw) -> ShapeModel:
        raise NotImplementedError


class ScreenGrid(ScreenScene):
    """3x3 dark discs on a bright plane seen by a pinhole camera (focal length = plane
    distance ``D``, so the rest pose is 1:1 in px); subclasses give the pose."""
    part_ids = [f"r{r}c{c}" for r in range(3) for c in range(3)]
    D = 500.0
    disc_value = 0.08

    def __init__(self, seed=0, spacing=45.0, radius=10.0):
        super().__init__(seed)
        self.spacing, self.radius = float(spacing), float(radius)
        self.plane = np.array([[(c - 1) * spacing, (r - 1) * spacing]
                               for r in range(3) for c in range(3)], float)

    def pose(self, t):
        """(ax, ay, az) radians, image shift (dx, dy) px."""
        raise NotImplementedError

    def offsets(self, t) -> np.ndarray:
        """(9, 2) displacement of each disc on the plane (not in the truth)."""
        return np.zeros((9, 2))

    def _project(self, pts, t):
        ax, ay, az, dx, dy = self.pose(t)
        R = _rotation(ax, ay, az)
        P = pts @ R[:, :2].T
        Z = self.D + P[:, 2]
        uv = np.column_stack([CX + dx + self.D * P[:, 0] / Z, CY + dy + self.D * P[:, 1] / Z])
        # d(uv)/d(plane X, Y): the affine image of a small disc about its centre
        J = np.empty((len(pts), 2, 2))
        for i in range(2):
            for j in range(2):
                J[:, i, j] = self.D * (R[i, j] * Z - P[:, i] * R[2, j]) / (Z * Z)
        return uv, J

    def truth(self, t):
        return self._project(self.plane, t)[0]

    def shapes(self, t):
        uv, J = self._project(self.plane + self.offsets(t), t)
        return np.array([shape(u, v, self.radius * j, self.disc_value)
                         for (u, v), j in zip(uv, J)])

    def initial_model(self, **kw):
        """grid3x3 at the rest pose, trackers the discs' rim covariance; ``kw``
        (stiffness, springs) go to the preset."""
        return grid3x3(CX, CY, self.spacing, sigma_px=self.radius * RIM_SIGMA, **kw)


class _Jitter:
    """A smooth random shift: 3 sinusoids per axis (0.4-1.6 Hz), ~1.5 px RMS in all."""

    def __init__(self, seed, tag, rms=1.5):
        rng = np.random.default_rng([seed, tag])
        self.f = rng.uniform(0.4, 1.6, size=(2, 3))
        self.ph = rng.uniform(0, 2 * math.pi, size=(2, 3))
        self.a = rms * math.sqrt(2.0 / 3.0)

    def __call__(self, t):
        s = np.sin(2 * math.pi * self.f * t + self.ph) - np.sin(self.ph)
        return self.a * s.sum(axis=1)


class GridPull(ScreenGrid):
    name = "grid_pull"
    default_seconds = 16.0
    PULLED = "r1c2"
    CYCLE_S = 8.0
    PULL_TIMES = (2.0, 3.5, 5.5, 7.0)    # out from, fully out at, back from, back at (s)

    def __init__(self, seed=0, pull_spacings=1.5, **kw):
        super().__init__(seed, **kw)
        self.pull_px = float(pull_spacings) * self.spacing
        self.k_pulled = self.part_ids.index(self.PULLED)
        self.jitter = _Jitter(self.seed, 21)

    def pose(self, t):
        j = self.jitter(t)
        return (math.radians(tri(t, 30.0, 15.0)), math.radians(tri(t, 45.0, 10.0)), 0.0,
                18.0 * math.sin(2 * math.pi * t / 7.0) + j[0],
                12.0 * math.sin(2 * math.pi * t / 5.0) + j[1])

    def pull_amount(self, t) -> float:
        """0 (in place) .. 1 (pulled by pull_spacings spacings)."""
        a, b, c, d = self.PULL_TIMES
        u = t % self.CYCLE_S
        return ramp((u - a) / (b - a)) * (1.0 - ramp((u - c) / (d - c)))

    def offsets(self, t):
        off = np.zeros((9, 2))
        off[self.k_pulled, 0] = self.pull_px * self.pull_amount(t)     # along the grid's X
        return off


class GridInplane(ScreenGrid):
    name = "grid_inplane"
    default_seconds = 12.0

    def __init__(self, seed=0, amplitude_deg=45.0, speed_deg_s=15.0, **kw):
        super().__init__(seed, **kw)
        self.amp, self.speed = float(amplitude_deg), float(speed_deg_s)
        self.jitter = _Jitter(self.seed, 22)

    def pose(self, t):
        j = self.jitter(t)
        return (0.0, 0.0, math.radians(tri(t, self.amp, self.speed)),
                25.0 * math.sin(2 * math.pi * t / 9.0) + j[0],
                15.0 * math.sin(2 * math.pi * t / 7.0) + j[1])


class GridRotY(ScreenGrid):
    name = "grid_rot_y"
    default_seconds = 16.0

    def __init__(self, seed=0, amplitude_deg=60.0, speed_deg_s=15.0, **kw):
        super().__init__(seed, **kw)
        self.amp, self.speed = float(amplitude_deg), float(speed_deg_s)
        self.jitter = _Jitter(self.seed, 23)

    def pose(self, t):
        j = self.jitter(t)
        return (0.0, math.radians(tri(t, self.amp, self.speed)), 0.0, j[0],
                20.0 * math.sin(2 * math.pi * t / 6.0) + j[1])


class FaceOcclusion(ScreenScene):
    """A face of height ``scale`` px: a skin ellipse with radii FACE_OUTLINE_RADII x scale
    before a dark wall, the internal parts dark ellipses of semi-axes sqrt(2) x the
    preset's sigmas; it drifts, rolls +-10 deg and grows by up to 15 %; a hand sweeps
    across the lower half in 2 s every 5 s from t = 3 s."""
    name = "face_occlusion"
    part_ids = list(face_layout())
    default_seconds = 16.0
    background = 0.12            # the wall
    skin, feature, hand_value = 0.75, 0.1, 0.45

    def __init__(self, seed=0, scale=110.0, hand_first=3.0, hand_period=5.0,
                 hand_duration=2.0, hand_size=0.17):
        super().__init__(seed)
        self.scale0 = float(scale)
        lay = face_layout()
        self.layout = np.array([lay[k][:2] for k in self.part_ids])
        self.sig = np.array([lay[k][2:] for k in self.part_ids])
        self.internal = [i for i, k in enumerate(self.part_ids) if not k.startswith("outline")]
        self.hand_first, self.hand_period = float(hand_first), float(hand_period)
        self.hand_duration, self.hand_size = float(hand_duration), float(hand_size)
        self.jitter = _Jitter(self.seed, 24, rms=1.0)

    def pose(self, t):
        """centre (x, y), face height (px), roll (rad)."""
        j = self.jitter(t)
        x = CX + 22.0 * math.sin(2 * math.pi * t / 7.0) + j[0]
        y = CY + 10.0 * math.sin(2 * math.pi * t / 5.5) + j[1]
        s = self.scale0 * (1.0 + 0.075 * (1.0 - math.cos(2 * math.pi * t / 12.0)))
        roll = math.radians(10.0) * math.sin(2 * math.pi * t / 4.5)
        return x, y, s, roll

    def _to_image(self, xy, t):
        x, y, s, roll = self.pose(t)
        c, sn = math.cos(roll), math.sin(roll)
        R = np.array([[c, -sn], [sn, c]])
        return np.array([x, y]) + s * xy @ R.T, s * R

    def truth(self, t):
        return self._to_image(self.layout, t)[0]

    def hand(self, t):
        if t < self.hand_first:
            return []
        k, u = divmod(t - self.hand_first, self.hand_period)
        if u > self.hand_duration:
            return []
        x, y, s, _ = self.pose(t)
        r = self.hand_size * s
        span = WIDTH + 4 * r
        hx = -2 * r + span * u / self.hand_duration
        if int(k) % 2:
            hx = WIDTH - hx
        hy = y + (0.25 if int(k) % 3 != 1 else 0.1) * s
        v = self.hand_value
        rows = [shape(hx, hy, np.diag([r, 1.15 * r]), v),
                shape(hx + 1.1 * r, hy + 0.3 * r, np.diag([0.7 * r, 0.25 * r]), v)]   # thumb
        for j, fx in enumerate((-0.6, -0.2, 0.2, 0.6)):
            fl = (0.9 if j in (1, 2) else 0.75) * r
            rows.append(shape(hx + fx * r, hy - 1.1 * r - 0.55 * fl, np.diag([0.2 * r, fl]), v))
        return rows

    def shapes(self, t):
        centre, A = self._to_image(np.zeros((1, 2)), t)
        rx, ry = FACE_OUTLINE_RADII
        rows = [shape(centre[0, 0], centre[0, 1], A @ np.diag([rx, ry]), self.skin)]
        xy = self.truth(t)
        for i in self.internal:
            m = A @ np.diag(self.sig[i] * math.sqrt(2.0))
            rows.append(shape(xy[i, 0], xy[i, 1], m, self.feature))
        return np.array(rows + self.hand(t))

    def initial_model(self, **kw):
        """face26 at the rest pose; ``kw`` (stiffness) go to the preset."""
        x, y, s, _ = self.pose(0.0)
        return face26(x, y, s, **kw)


class Dots(ScreenScene):
    """A dark and a bright disc going back and forth between x = margin and
    WIDTH - margin at ``speed`` px/s on a mid-grey screen."""
    name = "dots"
    part_ids = ["dark", "bright"]
    default_seconds = 4.0
    background = 0.35

    def __init__(self, seed=0, speed=100.0, radius=6.0, margin=30.0):
        super().__init__(seed)
        self.speed, self.radius, self.margin = float(speed), float(radius), float(margin)
        if not self.speed >= 0 or not self.radius > 0:
            raise ValueError(f"dots: speed must be >= 0 and radius > 0, got {speed}, {radius}")

    def truth(self, t):
        half = 0.5 * (WIDTH - 2 * self.margin)
        x = CX + tri(t, half, self.speed)
        return np.array([[x, 80.0], [WIDTH - x, 160.0]])

    def shapes(self, t):
        (x0, y0), (x1, y1) = self.truth(t)
        return np.array([shape(x0, y0, self.radius, 0.05), shape(x1, y1, self.radius, 1.0)])

    def initial_model(self, **kw):
        """Two trackers, one per disc, linked by one zero-stiffness spring (a model needs
        a connection for its energy; it pulls nothing)."""
        from springtrack.model import Connection
        s2 = (self.radius * RIM_SIGMA) ** 2
        xy = self.truth(0.0)
        trackers = [TrackerSpec(k, float(x), float(y), (s2, 0.0, s2))
                    for k, (x, y) in zip(self.part_ids, xy)]
        return ShapeModel("dots", WIDTH, HEIGHT, trackers,
                          [Connection("dark", "bright", ("euclidean",), 0.0)], {},
                          source="screen scene dots")


class ShapesHandheld(ScreenScene):
    """Eight dark shapes of different sizes and elongations on a bright wall (a disc, a
    ring, ellipses, a bar, a small dot and a pair of touching discs), filmed by a camera
    held in the hand: the image shifts by a sum of three sinusoids per axis (1.2-3.5 Hz)
    whose RMS speed is ``speed`` px/s, rolls by up to 3 deg and zooms by up to 3 %; a
    rigid scene of distinct parts for learning a model from a short window.  Its truth is
    each shape's centre; :meth:`transform` gives the whole image motion, so any point
    learned at one time can be scored at another."""
    name = "shapes_handheld"
    part_ids = [f"s{k}" for k in range(8)]
    default_seconds = 1.0
    background = 0.9
    value = 0.08

    def __init__(self, seed=0, speed=150.0):
        super().__init__(seed)
        self.speed = float(speed)
        if not self.speed >= 0:
            raise ValueError(f"shapes_handheld: speed must be >= 0, got {speed}")
        rng = np.random.default_rng([self.seed, 61])
        cells = np.array([[(c - 1.5) * 62.0, (r - 0.5) * 70.0] for r in range(2)
                          for c in range(4)])
        self.layout = cells + rng.uniform(-10.0, 10.0, size=cells.shape)

        def ellipse(a, b):
            th = rng.uniform(0.0, math.pi)
            c, s = math.cos(th), math.sin(th)
            return np.array([[c, -s], [s, c]]) @ np.diag([a, b])

        # (matrix, extra rows in shape coordinates: (dx, dy, matrix, value))
        self.kinds = [(12.0 * np.eye(2), []),                               # disc
                      (13.0 * np.eye(2), [(0.0, 0.0, 6.5 * np.eye(2), self.background)]),
                      (ellipse(15.0, 7.0), []),
                      (ellipse(18.0, 4.0), []),                             # bar
                      (6.0 * np.eye(2), []),                                # small dot
                      (ellipse(11.0, 8.0), []),
                      (7.0 * np.eye(2), [(14.0, 0.0, 7.0 * np.eye(2), self.value)]),  # pair
                      (ellipse(14.0, 10.0), [])]
        order = rng.permutation(len(self.kinds))
        self.kinds = [self.kinds[k] for k in order]
        self.f = rng.uniform(1.2, 3.5, size=(2, 3))
        self.ph = rng.uniform(0.0, 2 * math.pi, size=(2, 3))
        self.a = self.speed / (2 * math.pi * self.f * math.sqrt(3.0))
        self.rot = (math.radians(3.0), rng.uniform(0.4, 1.2), rng.uniform(0, 2 * math.pi))
        self.zoom = (0.03, rng.uniform(0.3, 1.0), rng.uniform(0, 2 * math.pi))

    def pose(self, t):
        """image shift (dx, dy) px, roll (rad), scale."""
        d = (self.a * (np.sin(2 * math.pi * self.f * t + self.ph) - np.sin(self.ph))).sum(axis=1)
        amp, f, ph = self.rot
        roll = amp * (math.sin(2 * math.pi * f * t + ph) - math.sin(ph))
        amp, f, ph = self.zoom
        scale = 1.0 + amp * (math.sin(2 * math.pi * f * t + ph) - math.sin(ph))
        return d[0], d[1], roll, scale

    def transform(self, t):
        """(A, b): the scene point at rest position p (px, about the sensor's centre)
        is seen at A p + b at time t."""
        dx, dy, roll, scale = self.pose(t)
        c, s = math.cos(roll), math.sin(roll)
        return scale * np.array([[c, -s], [s, c]]), np.array([CX + dx, CY + dy])

    def truth(self, t):
        A, b = self.transform(t)
        return self.layout @ A.T + b

    def shapes(self, t):
        A, b = self.transform(t)
        rows = []
        for (x, y), (m, extra) in zip(self.layout, self.kinds):
            u, v = A @ (x, y) + b
            rows.append(shape(u, v, A @ m, self.value))
            for ex, ey, em, val in extra:
                eu, ev = A @ (x + ex, y + ey) + b
                rows.append(shape(eu, ev, A @ em, val))
        return np.array(rows)

    def initial_model(self, **kw):
        """One tracker per shape at rest (its rim's covariance), each linked to its two
        nearest neighbours by a Euclidean spring (stiffness ``kw.get('stiffness', 0.001)``)."""
        from springtrack.model import Connection
        xy = self.truth(0.0)
        trackers = []
        for k, (x, y), (m, _) in zip(self.part_ids, xy, self.kinds):
            c = 0.5 * m @ m.T
            trackers.append(TrackerSpec(k, float(x), float(y), (c[0, 0], c[0, 1], c[1, 1])))
        links = set()
        for i in range(len(xy)):
            dist = np.hypot(*(xy - xy[i]).T)
            for j in np.argsort(dist)[1:3]:
                links.add((min(i, int(j)), max(i, int(j))))
        conns = [Connection(self.part_ids[i], self.part_ids[j], ("euclidean",),
                            float(kw.get("stiffness", 0.001))) for i, j in sorted(links)]
        return ShapeModel("shapes_handheld", WIDTH, HEIGHT, trackers, conns, {},
                          source="screen scene shapes_handheld")


SCENES: dict[str, type[ScreenScene]] = {c.name: c for c in
                                         (GridPull, GridInplane, GridRotY, FaceOcclusion, Dots,
                                          ShapesHandheld)}


def make_scene(name, seed: int = 0, **params) -> ScreenScene:
    """A screen scene by name; unknown names raise ValueError naming the known ones."""
    if isinstance(name, ScreenScene):
        return name
    if name not in SCENES:
        raise ValueError(f"unknown screen scene {name!r}; known: {', '.join(SCENES)}")
    return SCENES[name](seed=seed, **params)
