"""Shape models: Gaussian trackers linked by springs, read from and written to TOML.

Schema (one file per model)::

    name = "grid3x3"
    [sensor]
    width = 304
    height = 240
    [[trackers]]
    id = "r0c0"                  # unique string
    x = 100.0                    # initial mean, px
    y = 80.0
    sigma = [25.0, 0.0, 25.0]    # initial covariance [sxx, sxy, syy], px^2
    mass = 1.0
    [[connections]]
    a = "r0c0"
    b = "r0c1"
    springs = ["cartesian"]      # non-empty subset of euclidean, torsional, cartesian
    stiffness = 0.001
    [params]                     # optional, see springtrack.params
    alpha_position = 0.02

Equilibrium lengths, angles and offsets (eqs. 10, 14, 18) and the offsets from the
centre of mass G (eq. 22) are derived from the initial positions.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import limits as _limits
from . import params as _params
from .limits import MAX_CONNECTIONS, MAX_TRACKERS
from .wire import Nack

SPRING_KINDS = ("euclidean", "torsional", "cartesian")
SPRING_BIT = {"euclidean": 1, "torsional": 2, "cartesian": 4}


class ModelError(ValueError):
    """A model file or model object is invalid; the message names file and entry.
    ``code``: the host link's NACK code for it."""
    code = Nack.INVALID_MODEL


class ModelNameError(ModelError):
    """A model name INFO cannot carry (``limits.check_name``)."""
    code = Nack.TOO_LONG


@dataclass(frozen=True)
class TrackerSpec:
    id: str
    x: float
    y: float
    sigma: tuple[float, float, float]
    mass: float = 1.0


@dataclass(frozen=True)
class Connection:
    a: str
    b: str
    springs: tuple[str, ...]
    stiffness: float


@dataclass
class ShapeModel:
    name: str
    width: int
    height: int
    trackers: list[TrackerSpec]
    connections: list[Connection]
    params: dict = field(default_factory=dict)
    source: str = "<model>"
    # a learned model's evidence (springtrack.learning: stability, persistence, layout,
    # window_ms, events); numbers only, informative, never read by the tracker
    learned: dict = field(default_factory=dict)

    def __post_init__(self):
        validate(self)

    # ---- derived geometry -------------------------------------------------
    @property
    def ids(self) -> list[str]:
        return [t.id for t in self.trackers]

    def index(self, tracker_id: str) -> int:
        return self.ids.index(tracker_id)

    def arrays(self) -> dict:
        """Flat float64/int arrays of the model, as the kernels consume them."""
        idx = {t.id: i for i, t in enumerate(self.trackers)}
        x = np.array([t.x for t in self.trackers], dtype=np.float64)
        y = np.array([t.y for t in self.trackers], dtype=np.float64)
        mass = np.array([t.mass for t in self.trackers], dtype=np.float64)
        sig = np.array([t.sigma for t in self.trackers], dtype=np.float64).reshape(-1, 3)
        ca = np.array([idx[c.a] for c in self.connections], dtype=np.int32)
        cb = np.array([idx[c.b] for c in self.connections], dtype=np.int32)
        kinds = np.array([sum(SPRING_BIT[s] for s in c.springs) for c in self.connections],
                         dtype=np.int32)
        stiff = np.array([c.stiffness for c in self.connections], dtype=np.float64)
        # eqs. (10), (14), (18): equilibrium from the initial positions
        dx0 = x[cb] - x[ca]
        dy0 = y[cb] - y[ca]
        l0 = np.hypot(dx0, dy0)
        th0 = np.arctan2(dy0, dx0)
        # eq. (22): offsets from the mass-weighted centre of mass G
        gx = float(np.sum(mass * x) / np.sum(mass))
        gy = float(np.sum(mass * y) / np.sum(mass))
        return dict(x=x, y=y, mass=mass, sxx=sig[:, 0].copy(), sxy=sig[:, 1].copy(),
                    syy=sig[:, 2].copy(), ca=ca, cb=cb, kinds=kinds, stiffness=stiff,
                    dx0=dx0, dy0=dy0, l0=l0, th0=th0, gdx0=x - gx, gdy0=y - gy)

    def to_toml(self) -> str:
        return dumps(self)

    def save(self, path) -> None:
        Path(path).write_text(dumps(self))

    def digest(self) -> str:
        """Short content hash (sha256 of the canonical TOML), for telemetry/INFO."""
        return hashlib.sha256(dumps(self).encode()).hexdigest()[:16]


# ---- validation -------------------------------------------------------------
def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def validate(m: ShapeModel) -> None:
    src = m.source

    def err(msg):
        raise ModelError(f"{src}: {msg}")

    try:
        _limits.check_name(m.name)
    except _limits.NameTooLong as e:
        raise ModelNameError(f"{src}: {e}") from None
    except _limits.LimitError as e:
        err(str(e))
    if not m.trackers:
        err("a model needs at least one [[trackers]] entry")
    if len(m.trackers) > MAX_TRACKERS:
        err(f"{len(m.trackers)} trackers exceed the kernel capacity of {MAX_TRACKERS}")
    if len(m.connections) > MAX_CONNECTIONS:
        err(f"{len(m.connections)} connections exceed the kernel capacity of {MAX_CONNECTIONS}")
    seen = set()
    for i, t in enumerate(m.trackers):
        where = f"trackers[{i}] (id={t.id!r})"
        if not isinstance(t.id, str) or not _limits.TRACKER_ID.fullmatch(t.id):
            err(f"trackers[{i}]: id {t.id!r:.60} is not a tracker id: 1 to "
                f"{_limits.TRACKER_ID_MAX} characters of {_limits.TRACKER_ID_CHARS} (ids name "
                f"the columns of CSV files and telemetry)")
        if t.id in seen:
            err(f"{where}: duplicate tracker id {t.id!r}")
        seen.add(t.id)
        for key in ("x", "y", "mass"):
            if not _finite(getattr(t, key)):
                err(f"{where}: {key} must be a finite number, got {getattr(t, key)!r}")
        if t.mass <= 0:
            err(f"{where}: mass must be positive, got {t.mass}")
        if len(t.sigma) != 3 or not all(_finite(v) for v in t.sigma):
            err(f"{where}: sigma must be three finite numbers [sxx, sxy, syy], got {list(t.sigma)!r}")
        sxx, sxy, syy = t.sigma
        if sxx <= 0 or syy <= 0 or sxx * syy - sxy * sxy <= 0:
            err(f"{where}: sigma {list(t.sigma)} is not positive definite")
    pairs = set()
    for k, c in enumerate(m.connections):
        where = f"connections[{k}] ({c.a!r}-{c.b!r})"
        for end in (c.a, c.b):
            if not isinstance(end, str) or end not in seen:
                err(f"{where}: unknown tracker id {end!r}")
        if c.a == c.b:
            err(f"{where}: a connection from a tracker to itself")
        if not isinstance(c.springs, (list, tuple)) or not c.springs:
            err(f"{where}: springs must be a non-empty subset of {', '.join(SPRING_KINDS)}")
        for s in c.springs:
            if not isinstance(s, str) or s not in SPRING_KINDS:
                err(f"{where}: unknown spring kind {s!r}; use {', '.join(SPRING_KINDS)}")
        if len(set(c.springs)) != len(c.springs):
            err(f"{where}: a spring kind is listed twice in {list(c.springs)}")
        if not _finite(c.stiffness):
            err(f"{where}: stiffness must be a finite number, got {c.stiffness!r}")
        if c.stiffness < 0:
            err(f"{where}: stiffness must not be negative, got {c.stiffness}")
        pair = frozenset((c.a, c.b))
        if pair in pairs:
            err(f"{where}: duplicate connection between {c.a!r} and {c.b!r}")
        pairs.add(pair)
    try:
        _limits.check_model(m.width, m.height, m.arrays(), m.ids)
    except _limits.LimitError as e:
        err(str(e))
    try:
        _params.from_mapping(m.params, where=f"{src} [params]")
    except _params.ParamError as e:
        raise ModelError(str(e)) from None


# ---- TOML I/O ---------------------------------------------------------------
def _q(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _f(v: float) -> str:
    return repr(float(v))


def _v(v) -> str:
    if isinstance(v, str):
        return _q(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    return _f(v)


def dumps(m: ShapeModel) -> str:
    out = [f"name = {_q(m.name)}", "", "[sensor]", f"width = {m.width}", f"height = {m.height}"]
    for t in m.trackers:
        out += ["", "[[trackers]]", f"id = {_q(t.id)}", f"x = {_f(t.x)}", f"y = {_f(t.y)}",
                "sigma = [" + ", ".join(_f(v) for v in t.sigma) + "]", f"mass = {_f(t.mass)}"]
    for c in m.connections:
        out += ["", "[[connections]]", f"a = {_q(c.a)}", f"b = {_q(c.b)}",
                "springs = [" + ", ".join(_q(s) for s in c.springs) + "]",
                f"stiffness = {_f(c.stiffness)}"]
    if m.params:
        out += ["", "[params]"] + [f"{k} = {_v(v)}" for k, v in m.params.items()]
    if m.learned:
        out += ["", "[learned]"] + [f"{k} = {_v(v)}" for k, v in m.learned.items()]
    return "\n".join(out) + "\n"


def _need(d: dict, key: str, where: str, src: str):
    if key not in d:
        raise ModelError(f"{src}: {where}: missing key {key!r}")
    return d[key]


def _tables(data: dict, key: str, source: str) -> list:
    """``data[key]``, an array of tables ([[key]] entries), or a ModelError saying so."""
    v = data.get(key, [])
    if not isinstance(v, list) or not all(isinstance(t, dict) for t in v):
        raise ModelError(f"{source}: {key} must be an array of tables ([[{key}]] entries), "
                         f"got {type(v).__name__} {v!r:.40}")
    return v


def from_dict(data: dict, source: str = "<model>") -> ShapeModel:
    """Build a model from parsed TOML, with errors naming ``source`` and the entry."""
    unknown = set(data) - {"name", "sensor", "trackers", "connections", "params", "learned"}
    if unknown:
        raise ModelError(f"{source}: unknown top-level key(s) {sorted(unknown)}")
    sensor = data.get("sensor")
    if not isinstance(sensor, dict):
        raise ModelError(f"{source}: missing [sensor] table with width and height")
    trackers = []
    for i, t in enumerate(_tables(data, "trackers", source)):
        where = f"trackers[{i}]"
        extra = set(t) - {"id", "x", "y", "sigma", "mass"}
        if extra:
            raise ModelError(f"{source}: {where}: unknown key(s) {sorted(extra)}")
        sigma = _need(t, "sigma", where, source)
        if not isinstance(sigma, list):
            raise ModelError(f"{source}: {where}: sigma must be a list [sxx, sxy, syy]")
        trackers.append(TrackerSpec(_need(t, "id", where, source), _need(t, "x", where, source),
                                    _need(t, "y", where, source), tuple(sigma), t.get("mass", 1.0)))
    conns = []
    for k, c in enumerate(_tables(data, "connections", source)):
        where = f"connections[{k}]"
        extra = set(c) - {"a", "b", "springs", "stiffness"}
        if extra:
            raise ModelError(f"{source}: {where}: unknown key(s) {sorted(extra)}")
        springs = _need(c, "springs", where, source)
        if not isinstance(springs, list):
            raise ModelError(f"{source}: {where}: springs must be a list of strings")
        conns.append(Connection(_need(c, "a", where, source), _need(c, "b", where, source),
                                tuple(springs), _need(c, "stiffness", where, source)))
    params = data.get("params", {})
    if not isinstance(params, dict):
        raise ModelError(f"{source}: [params] must be a table")
    return ShapeModel(name=data.get("name", ""), width=_need(sensor, "width", "[sensor]", source),
                      height=_need(sensor, "height", "[sensor]", source), trackers=trackers,
                      connections=conns, params=dict(params), source=source,
                      learned=_learned_table(data.get("learned", {}), source))


def _learned_table(t, source: str) -> dict:
    """The ``[learned]`` table: a learned model's evidence, names to finite numbers."""
    if not isinstance(t, dict):
        raise ModelError(f"{source}: [learned] must be a table")
    bad = [k for k, v in t.items() if not _finite(v)]
    if bad:
        raise ModelError(f"{source}: [learned]: {bad[0]} must be a finite number")
    return dict(t)


def loads(text, source: str = "<string>") -> ShapeModel:
    """A model from TOML text (str or UTF-8 bytes); errors name ``source``."""
    return from_dict(_params.parse_toml(text, source, ModelError), source)


def load(path) -> ShapeModel:
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise ModelError(f"{path}: cannot read model file: {e.strerror or e}") from None
    return loads(data, str(path))


# ---- presets ----------------------------------------------------------------
def grid3x3(cx: float = 152.0, cy: float = 120.0, spacing: float = 50.0, sigma_px: float = 5.0,
            stiffness: float = 0.001, springs=("cartesian",), width: int = 304,
            height: int = 240) -> ShapeModel:
    """Paper IV-A: 3x3 grid, 12 four-neighbour connections (Cartesian by default).
    Tracker ids ``r{row}c{col}``; grid side = 2 * spacing."""
    trackers = [TrackerSpec(f"r{r}c{c}", cx + (c - 1) * spacing, cy + (r - 1) * spacing,
                            (sigma_px ** 2, 0.0, sigma_px ** 2)) for r in range(3) for c in range(3)]
    conns = []
    for r in range(3):
        for c in range(3):
            if c < 2:
                conns.append(Connection(f"r{r}c{c}", f"r{r}c{c + 1}", tuple(springs), stiffness))
            if r < 2:
                conns.append(Connection(f"r{r}c{c}", f"r{r + 1}c{c}", tuple(springs), stiffness))
    kind = "cartesian" if "cartesian" in springs else "euclidean"
    params = {"alpha_position": 0.02, "alpha_covariance": 5e-5, "energy_scale": 4.5,
              "energy_kind": kind}
    return ShapeModel("grid3x3", width, height, trackers, conns, params, source="preset grid3x3")


# Face layout in units of the face height (y down, origin at the face centre),
# and each part's standard deviations (sx, sy) in the same unit.
FACE_PARTS = {
    "brow_l": ((-0.17, -0.21), (0.060, 0.020)),
    "brow_r": ((0.17, -0.21), (0.060, 0.020)),
    "eye_l": ((-0.16, -0.09), (0.045, 0.025)),
    "eye_r": ((0.16, -0.09), (0.045, 0.025)),
    "nostril_l": ((-0.05, 0.11), (0.022, 0.018)),
    "nostril_r": ((0.05, 0.11), (0.022, 0.018)),
    "mouth": ((0.0, 0.27), (0.090, 0.028)),
}
FACE_INTERNAL = tuple(FACE_PARTS)
FACE_OUTLINE_N = 19
FACE_OUTLINE_RADII = (0.36, 0.5)
FACE_OUTLINE_SIGMA = 0.03
FACE_INTERNAL_LINKS = [("brow_l", "brow_r"), ("eye_l", "eye_r"), ("nostril_l", "nostril_r"),
                       ("brow_l", "eye_l"), ("brow_r", "eye_r"), ("eye_l", "nostril_l"),
                       ("eye_r", "nostril_r"), ("nostril_l", "mouth"), ("nostril_r", "mouth")]
FACE_SPOKES = {"brow_l": 2, "brow_r": 2, "eye_l": 2, "eye_r": 2, "nostril_l": 1,
               "nostril_r": 1, "mouth": 2}


def face_layout() -> dict[str, tuple[float, float, float, float]]:
    """Part id -> (x, y, sx, sy) in face-height units; shared with the simulator."""
    out = {k: (p[0], p[1], s[0], s[1]) for k, (p, s) in FACE_PARTS.items()}
    rx, ry = FACE_OUTLINE_RADII
    for k in range(FACE_OUTLINE_N):
        a = -math.pi / 2 + 2 * math.pi * k / FACE_OUTLINE_N   # start at the top, clockwise
        out[f"outline{k:02d}"] = (rx * math.cos(a), ry * math.sin(a),
                                  FACE_OUTLINE_SIGMA, FACE_OUTLINE_SIGMA)
    return out


def face26(cx: float = 152.0, cy: float = 120.0, scale: float = 120.0, stiffness: float = 0.02,
           width: int = 304, height: int = 240) -> ShapeModel:
    """Paper IV-B, Fig. 18: 7 internal parts + 19 outline trackers, 40 Euclidean+torsional
    connections (19 around the outline, 9 between internal parts, 12 internal-to-outline).
    ``scale`` is the face height in px."""
    lay = face_layout()
    trackers = [TrackerSpec(k, cx + scale * x, cy + scale * y,
                            ((scale * sx) ** 2, 0.0, (scale * sy) ** 2))
                for k, (x, y, sx, sy) in lay.items()]
    springs = ("euclidean", "torsional")
    links = [(f"outline{k:02d}", f"outline{(k + 1) % FACE_OUTLINE_N:02d}")
             for k in range(FACE_OUTLINE_N)]
    links += FACE_INTERNAL_LINKS
    outline = [f"outline{k:02d}" for k in range(FACE_OUTLINE_N)]
    for part, n in FACE_SPOKES.items():
        px, py = lay[part][:2]
        near = sorted(outline, key=lambda o: (lay[o][0] - px) ** 2 + (lay[o][1] - py) ** 2)
        links += [(part, o) for o in near[:n]]
    conns = [Connection(a, b, springs, stiffness) for a, b in links]
    return ShapeModel("face26", width, height, trackers, conns, {}, source="preset face26")


PRESETS = {"grid3x3": grid3x3, "face26": face26}


def load_model(path_or_preset) -> ShapeModel:
    """A preset name (``grid3x3``, ``face26``) or a path to a TOML model file."""
    if isinstance(path_or_preset, ShapeModel):
        return path_or_preset
    key = str(path_or_preset)
    if key in PRESETS and not Path(key).exists():
        return PRESETS[key]()
    if not Path(key).exists():
        raise ModelError(f"{key}: no such model file, and not a preset ({', '.join(PRESETS)})")
    return load(key)
