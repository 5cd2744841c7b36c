"""The learner: ``learn_model`` and ``learn`` from the three passes (springtrack.learning),
the model built from them, and its tracking parameters learned from the same record."""
from __future__ import annotations

import math
import time

import numpy as np

from ..events import as_events
from ..limits import MAX_CONNECTIONS, spring_scale
from ..model import SPRING_BIT, Connection, ShapeModel, TrackerSpec
from .motion import MOTION_ON, SPEED_QUANTILE, fast_enough, sets_motion, sizes_per_ms
from ..params import Params
from .discovery import (_discover, _keep_cols, _to_count, awake, dominant, event_rates,
                        event_shares, join_edges, join_outlines, quiet_nan,
                        reference_value)
from .flicker import FLICKER_SHARE, mains_flicker
from .pool import Pool
from .settings import (F, LearnParams, LearnResult, MASS_RANGE, MAX_PARTS, MIN_EVENTS,
                       NoObjectFound, PERSIST_GRACES, PERSIST_MIN, POINT_SIGMA,
                       COHERENCE_MIN, WEAK_PASSES)
from .springs import _springs, activity_weights, object_similarity


# ---- the learner ------------------------------------------------------------------------
def learn_model(events, trackers: int | None = None, width: int | None = None,
                height: int | None = None, names=None, name: str = "learned",
                params: LearnParams | dict | None = None,
                track_params: dict | None = None) -> LearnResult:
    """Learn a shape model from ``events`` (structured t µs, x, y, p; time order).

    ``trackers``: exactly this many parts (default: the learner's choice); ``width`` x
    ``height``: the sensor (default: the events' extent); ``names``: tracker ids (default
    p00, p01, ... in reading order: top to bottom, left to right); ``params``: learner
    parameters (:class:`LearnParams` or a dict of overrides); ``track_params``: tracking
    parameters (springtrack.params names) to write into the model's ``[params]`` as
    given; alpha_position, alpha_covariance, energy_scale and energy_kind are learned
    unless given there (the stiffness scales with alpha_position).
    Raises :class:`NoObjectFound` when no part survives.
    """
    wall0 = time.perf_counter()
    lp = params if isinstance(params, LearnParams) else LearnParams(**(params or {}))
    tp = Params(**(track_params or {})).as_dict()             # validated
    tp = {k: tp[k] for k in (track_params or {})}
    ev = as_events(events)
    if trackers is not None and not 1 <= int(trackers) <= MAX_PARTS:
        raise ValueError(f"learn: trackers must be in [1, {MAX_PARTS}] (one kernel instance "
                         f"holds at most {MAX_PARTS}), got {trackers}")
    if len(ev) < MIN_EVENTS:
        raise NoObjectFound(f"no object found: the learning window holds {len(ev):,} events, "
                            f"fewer than the {MIN_EVENTS:,} a model needs; give a longer window "
                            f"(--end-us, --learn-first-ms)")
    if np.any(np.diff(ev["t"]) < 0):
        raise ValueError("learn: events must be in time order")
    width = int(width) if width else int(ev["x"].max()) + 1
    height = int(height) if height else int(ev["y"].max()) + 1
    t0, t1 = int(ev["t"][0]), int(ev["t"][-1])
    lp = lp.for_window(t1 - t0)
    stats = {"born": 0, "merged": 0, "outline_merged": 0, "end_outline_merged": 0,
             "edge_merged": 0, "died": 0, "birth_refused_full": 0, "weak": 0,
             "dropped_to_n": 0, "merged_to_n": 0, "split_to_n": 0, "found": 0,
             "time_scale": round(lp.batch_us / LearnParams().batch_us, 4)}
    pool = Pool(lp, width, height)
    history = _discover(pool, ev, t0, t1, stats)
    # trackers still in their grace period are not parts yet, and a part has an extent
    # (a hot pixel makes a tracker as narrow as sigma_min_px both ways)
    st = pool.st[:, :pool.n]
    point = np.maximum(st[F["sxx"]], st[F["syy"]]) <= (POINT_SIGMA * lp.sigma_min_px) ** 2
    pool.keep(((t1 - pool.book["born"][:pool.n]) > lp.life_tau_us) & ~point)
    if pool.n == 0:
        raise NoObjectFound(f"no object found: no tracker lived through its grace period of "
                            f"{lp.life_tau_us / 1e3:g} ms in {len(ev):,} events over "
                            f"{(t1 - t0) / 1e3:g} ms ({stats['born']} born, "
                            f"{stats['died']} died); try a longer window (--end-us, "
                            f"--learn-first-ms) or a shorter grace period (--learn-param "
                            f"life_tau_us=US)")
    rec = history.series(pool.book["uid"][:pool.n], pool.lineage)
    rec = join_outlines(pool, rec, t1, stats)
    rec = join_edges(pool, rec, t1, stats)
    if trackers is None:
        # pieces of parts that no merge joined take a small share of the events, and
        # trackers left behind by their part take none at the end
        # (both measured against the median part, or a dominant part: with one part
        # holding half the events, the faint trails it leaves are the many)
        # (once the many are gone a dominant part's faint trails are judged again, until
        # none is left: against a dominant part, not the median, no real part cascades)
        for _ in range(WEAK_PASSES):
            wake = awake(rec, lp.activity_tau_us, lp.batch_us)
            share = event_shares(rec)
            held = rec["cnt"].sum(axis=0)
            weak = ((share < lp.keep_share * max(1.0, reference_value(share, held)))
                    | (wake < lp.idle_share * reference_value(wake, held)))
            if not weak.any() or weak.all():
                break
            stats["weak"] += int(weak.sum())
            pool.keep(~weak)
            rec = _keep_cols(rec, ~weak)
            held = rec["cnt"].sum(axis=0)
            if not dominant(held):
                break
        stats["found"] = pool.n
        if pool.n > MAX_PARTS:
            # more parts than one kernel instance holds: the weakest dropped, then the
            # nearest merged, down to the capacity
            rec = _to_count(pool, rec, MAX_PARTS, t1, stats)
    elif pool.n != int(trackers):
        stats["found"] = pool.n
        rec = _to_count(pool, rec, int(trackers), t1, stats)
    counts = rec["cnt"].sum(axis=0)
    if pool.n == 0 or counts.sum() == 0:
        raise NoObjectFound("no object found: the learned trackers took no events")
    model, springs, cands, counts = _build_model(pool, rec, counts, lp, tp, width, height,
                                                 names, name, stats["outline_merged"])
    model.learned = stability(rec, springs, cands, lp, t0, t1, len(ev)) | model.learned
    hz, share = mains_flicker(ev["t"])
    if share >= FLICKER_SHARE:
        model.learned.update(flicker_hz=hz, flicker_share=round(share, 3))
    if model.learned["persistence"] < PERSIST_MIN:
        life = PERSIST_GRACES * lp.life_tau_us / 1e3
        raise NoObjectFound(
            f"no stable object: persistence {model.learned['persistence']:.2f} < "
            f"{PERSIST_MIN} (the median of the {len(model.trackers)} parts lived "
            f"{model.learned['persistence'] * life:.3g} ms of the {life:.3g} ms that make a "
            f"persistent part, in a {(t1 - t0) / 1e3:g} ms window): short-lived activity "
            f"(sparks, noise, flicker); try a longer window (--end-us, --learn-first-ms) or "
            f"a recording where an object moves as a whole")
    if model.learned["coherence"] < COHERENCE_MIN:
        raise NoObjectFound(
            f"no stable object: coherence {model.learned['coherence']:.2f} < {COHERENCE_MIN} "
            f"(of the neighbouring pairs of the {len(model.trackers)} parts found, that share "
            f"fired together): the activity is sparks or noise, each part on its own, not an "
            f"object moving as a whole; try a longer window (--end-us, --learn-first-ms) or a "
            f"recording where an object moves")
    return LearnResult(model, len(ev), int(counts.sum()), t0, t1, counts, springs, cands,
                       stats, time.perf_counter() - wall0)


def stability(rec: dict, springs: list, candidates: list, lp: LearnParams, t0: int,
              t1: int, events: int) -> dict:
    """A learned model's evidence, written into its ``[learned]`` table.

    ``persistence``: the median over the parts of how long each part (or the pieces it
    merged from) existed, in units of PERSIST_GRACES grace periods (``life_tau_us``),
    at most 1: a part that outlived its grace period twice persisted; sparks, flicker
    and noise make trackers that barely outlive theirs.  ``layout``: the median rigidity
    (springs.rigidity: 1 = the pair kept its relative position in the object's frame) of
    the springs kept, 1 for a single part, 0 for several with no spring.
    ``coherence``: the share of neighbouring pairs (the spring candidates) that were
    co-active (``min_coactivation``): the parts of one object fire together as it
    moves, sparks and noise each on their own; 1 for a single part.
    ``stability`` = persistence x coherence x layout, in [0, 1].  ``travel_px``: the
    median over the parts of how far each moved from its median place within the window
    (largest distance, px): a part that did not move was seen through flicker or noise,
    not motion, and its springs' rigidity was never put to the test."""
    lived = rec["valid"].sum(axis=0) * float(lp.batch_us)
    with quiet_nan():
        dx = rec["x"] - np.nanmedian(rec["x"], axis=0)
        dy = rec["y"] - np.nanmedian(rec["y"], axis=0)
        reach = np.nanmax(np.hypot(dx, dy), axis=0)
    travel = float(np.median(reach[np.isfinite(reach)])) if np.isfinite(reach).any() else 0.0
    n = len(lived)
    persistence = (float(np.median(np.minimum(1.0, lived / (PERSIST_GRACES * lp.life_tau_us))))
                   if n else 0.0)
    if n == 1:
        layout = coherence = 1.0
    else:
        layout = float(np.median([c.rigidity for c in springs])) if springs else 0.0
        coherence = (float(np.mean([c.coactivation >= lp.min_coactivation for c in candidates]))
                     if candidates else 0.0)
    return {"stability": round(persistence * coherence * layout, 3),
            "persistence": round(persistence, 3), "coherence": round(coherence, 3),
            "layout": round(layout, 3), "travel_px": round(travel, 2),
            "window_ms": round((t1 - t0) / 1e3, 3),
            "events": int(events)}


def reading_order(x: np.ndarray, y: np.ndarray, row_px: float) -> np.ndarray:
    """Indices of the points in reading order: rows top to bottom (a new row starts
    ``row_px`` below the first point of the current one), left to right in a row."""
    by_y = np.argsort(y, kind="stable")
    row = np.zeros(len(y), int)
    start = y[by_y[0]] if len(y) else 0.0
    for k in range(1, len(by_y)):
        row[k] = row[k - 1]
        if y[by_y[k]] - start > row_px:
            row[k] += 1
            start = y[by_y[k]]
    rows = np.empty(len(y), int)
    rows[by_y] = row
    return np.lexsort((x, rows))


def similarity_fit(z: np.ndarray, ref: np.ndarray, w: np.ndarray):
    """The similarity ``z ~ zbar + a (ref - rbar)`` (complex points (N,), weights (N,)):
    returns (a, zbar, rbar); a = 0 with fewer than two weighted points."""
    ws = max(float(w.sum()), 1e-300)
    zbar, rbar = (w * z).sum() / ws, (w * ref).sum() / ws
    den = float((w * np.abs(ref - rbar) ** 2).sum())
    a = (w * (z - zbar) * np.conj(ref - rbar)).sum() / den if den > 0 else 0.0
    return a, zbar, rbar


def steady_positions(rec: dict, x_end: np.ndarray, y_end: np.ndarray, size_px: float,
               rounds: int = 3, gate: float = 1.0):
    """The final positions (x, y) (N,), each tracker caught off its part at the window's
    end put back where the object's shape over the window places it.

    The final positions are one instant of free trackers, each with its own jitter and
    lag; a part caught a few pixels off at that instant would put a constant strain on
    the springs (their rest geometry is the model's positions) that the energy criteria,
    eqs. (21)-(22), would then misread.  The shape is the mean of the samples, each
    carried into the shape's frame by the similarity that maps the shape onto it
    (:func:`object_similarity`, activity-weighted), starting from the final positions and
    repeated ``rounds`` times (generalised Procrustes analysis); a sample counts with
    weight exp(-d^2 / (2 size_px^2)), d the RMS distance of its carried positions from
    the shape.  The shape is placed on the final positions by the similarity that maps it
    there, and a tracker farther than ``size_px`` (a part's size) from its place takes
    it; the others keep their final positions (where the parts are: a perspective view
    is not a similarity).  When most samples are no similarity of one shape (the median
    d over ``gate`` x ``size_px``, the reach of a tracker's gate, eq. (2): a 3-D turn, a
    deforming object), the final positions stay.  (A part seen through its edges -- its
    leading and trailing edges fire apart, its trackers slide along them as the motion
    turns -- stays within that reach; a turn in depth does not.)

    Returns (x, y, one_shape): one_shape False when the object's shape itself changed."""
    X, Y = rec["x"], rec["y"]
    w0 = activity_weights(rec)
    z = np.where(w0 > 0, X + 1j * Y, 0.0)
    end = x_end + 1j * y_end
    shape = end.copy()
    for _ in range(rounds):
        a = object_similarity(X, Y, w0, shape.real, shape.imag)              # (T,)
        ok = np.abs(a) > 0
        if not ok.any():
            return x_end, y_end, True
        ws = np.maximum(w0.sum(axis=1), 1e-300)
        zbar = (w0 * z).sum(axis=1) / ws
        rbar = (w0 * shape[None, :]).sum(axis=1) / ws
        inv = np.where(ok, 1.0 / np.where(ok, a, 1.0), 0.0)
        est = rbar[:, None] + (z - zbar[:, None]) * inv[:, None]              # (T, N)
        d2 = (w0 * np.abs(est - shape[None, :]) ** 2).sum(axis=1) / ws
        if np.median(d2[ok]) > (gate * size_px) ** 2:
            return x_end, y_end, False    # not one shape: the one at the end
        w = w0 * (ok * np.exp(-0.5 * d2 / size_px ** 2))[:, None]
        tot = w.sum(axis=0)
        shape = np.where(tot > 0, (w * est).sum(axis=0) / np.maximum(tot, 1e-300), end)
    a, zbar, rbar = similarity_fit(end, shape, np.ones(len(end)))
    if a == 0:
        return x_end, y_end, True
    placed = zbar + a * (shape - rbar)
    placed = np.where(np.abs(placed - end) > size_px, placed, end)
    return placed.real.copy(), placed.imag.copy(), True


def spring_energies(rec: dict, kept: list, stiffness: np.ndarray, kind: str, x_end,
                    y_end) -> np.ndarray:
    """(T, C) energies of the connections ``kept`` (LearnedSpring, pool indices) along the
    samples, as the tracker computes them with the final positions as its rest geometry,
    NaN where an end is missing: eq. (12) (euclidean: rest lengths l0) or eq. (20)
    (cartesian: rest offsets ``a d0`` carried by each sample's similarity ``a``,
    :func:`object_similarity`, as the tracker's similarity frame carries them)."""
    a = np.array([c.a for c in kept])
    b = np.array([c.b for c in kept])
    X, Y = rec["x"], rec["y"]
    r = (X[:, b] - X[:, a]) + 1j * (Y[:, b] - Y[:, a])
    r0 = (x_end[b] - x_end[a]) + 1j * (y_end[b] - y_end[a])
    if kind == "cartesian":
        sim = object_similarity(X, Y, activity_weights(rec), x_end, y_end)[:, None]
        return 0.5 * stiffness * np.abs(r - sim * r0) ** 2                  # eq. (20)
    dl = np.abs(r) - np.abs(r0)                                            # eq. (10)
    return 0.5 * stiffness * dl * dl                                        # eq. (12)


def part_speeds(rec: dict, batch_us: int, smooth_us: int) -> np.ndarray:
    """(N,) each tracker's RMS speed in px/s over the window, its positions averaged over
    ``smooth_us`` first (NaN where it has fewer than two such averages)."""
    step = max(1, int(round(smooth_us / batch_us)))
    T, n = rec["x"].shape
    m = T // step * step
    if m < 2 * step:
        return np.full(n, np.nan)
    with quiet_nan():
        bx = np.nanmean(rec["x"][:m].reshape(-1, step, n), axis=1)     # NaN: no sample
        by = np.nanmean(rec["y"][:m].reshape(-1, step, n), axis=1)
        v2 = np.nanmean(np.diff(bx, axis=0) ** 2 + np.diff(by, axis=0) ** 2, axis=0)
    return np.sqrt(v2) / (step * batch_us * 1e-6)


def motion_alpha(v: np.ndarray, rec: dict, sig: np.ndarray, batch_us: int,
                 lag_fraction: float, quantile: float = SPEED_QUANTILE,
                 bounds=(0.005, 0.5)) -> float:
    """alpha_1 of eq. (3) for the motion seen while learning.

    Between two of its events (1/r s apart) a part moving at v px/s moves by v / r px;
    the running mean of eq. (3) takes 1/alpha_1 events to catch up, so it lags by
    v / (alpha_1 r) px.  Held to ``lag_fraction`` of the part's size sigma:
    alpha_1 = v / (lag_fraction r sigma).  Each tracker's own v (``part_speeds``), r and
    sigma give its alpha_1; the model takes their ``quantile``, so that the parts that
    move fastest for their events (the tips of a turning object) are followed too."""
    r = event_rates(rec) / (batch_us * 1e-6)
    ok = np.isfinite(v) & (r > 0) & (sig > 0)
    if not ok.any():
        return Params().alpha_position
    # alpha_1 = v / (lag_fraction r sigma): eq. (3)'s lag v / (alpha_1 r) = lag_fraction sigma
    alpha = v[ok] / (lag_fraction * r[ok] * sig[ok])
    return float(np.clip(np.quantile(alpha, quantile), *bounds))


def energy_scale(energies: np.ndarray, quantile: float, floor: float,
                 ceiling: float = math.inf) -> float:
    """s of eqs. (21)-(22) such that the deformations seen while learning stay below it:
    the ``quantile`` of E_ij / mean(E) over the samples (NaN: missing), within
    [``floor``, ``ceiling``].  The ceiling keeps the criteria able to act: the window's
    clean motion says how unevenly the parts deform, not how hard an occluder will pull,
    and a few unevenly deforming pairs (an object's outline, texture) make the tail long;
    above about 5 the criteria no longer fire even on a part dragged off its place
    (docs/tuning.md), so a larger s would switch eqs. (21)-(22) off."""
    with quiet_nan():
        mean = np.nanmean(energies, axis=1, keepdims=True)
        ratio = energies / mean
    ratio = ratio[np.isfinite(ratio)]
    if not len(ratio):
        return floor
    return min(max(floor, float(np.quantile(ratio, quantile))), max(floor, ceiling))


def _build_model(pool, rec, counts, lp, track_params, width, height, names, name,
                 outlines=0):
    """The ShapeModel of the pool's trackers, with springs and tracking parameters:
    ``track_params`` (a dict) as given, the others learned (alpha_position: motion_alpha;
    alpha_covariance: alpha_position / covariance_ratio, at most the default;
    energy_scale: energy_scale; energy_kind: cartesian if every spring is; the motion
    model for fast parts; both edges, polarity_gain 1, where ``outlines`` pairs of pieces
    of one outline were merged)."""
    n = pool.n
    st = pool.st
    sig = np.sqrt(0.5 * (st[F["sxx"], :n] + st[F["syy"], :n]))
    x, y, one_shape = steady_positions(rec, pool.x.copy(), pool.y.copy(), float(np.median(sig)),
                                       gate=math.sqrt(lp.gate_d2))
    order = reading_order(x, y, float(np.median(sig)))
    if names is not None:
        names = list(names)
        if len(names) != n:
            raise ValueError(f"learn: {len(names)} names for {n} trackers")
    ids = names or [f"p{k:02d}" for k in range(n)]
    new_of = np.empty(n, int)
    new_of[order] = np.arange(n)
    mass = np.clip(event_shares(rec), MASS_RANGE[0], MASS_RANGE[1])
    trackers = [None] * n
    for i in range(n):
        trackers[new_of[i]] = TrackerSpec(ids[new_of[i]], float(x[i]), float(y[i]),
                                          (float(st[F["sxx"], i]), float(st[F["sxy"], i]),
                                           float(st[F["syy"], i])), float(mass[i]))
    cands = _springs(rec, sig, lp, x, y)
    coactive = [c for c in cands if c.kinds and c.coactivation >= lp.min_coactivation]
    kept = [c for c in coactive if c.rigidity >= lp.min_rigidity]
    # a tracker no rigid pair holds is tied by its most rigid co-active neighbour
    held = {e for c in kept for e in (c.a, c.b)}
    for i in range(n):
        if i not in held:
            mine = [c for c in coactive if i in (c.a, c.b) and c not in kept]
            if mine:
                best = max(mine, key=lambda c: c.rigidity * c.coactivation)
                kept.append(best)
                held.update((best.a, best.b))
    kept = sorted(kept, key=lambda c: -c.rigidity * c.coactivation)[:MAX_CONNECTIONS]
    params = dict(track_params)
    v = part_speeds(rec, lp.batch_us, lp.smooth_us)
    if "alpha_position" not in params:
        params["alpha_position"] = round(motion_alpha(v, rec, sig, lp.batch_us,
                                                      lp.lag_fraction), 4)
    fast = sizes_per_ms(v, sig)
    if fast_enough(fast, lp.motion_sigmas_per_ms) and not sets_motion(params):
        # fast parts: velocity and both edges per tracker (eqs. M1-M9) unless given
        params.update(MOTION_ON)
    elif outlines and not sets_motion(params):
        # uniform parts (the outline merge joined the pieces of their outlines) fire their
        # ON and OFF edges apart by their size: a half offset per tracker (eq. M6b) puts
        # its mean between them, where one mean for both sits on the busier edge
        params["polarity_gain"] = 1.0
    kalman = float(params.get("motion_tau_us", 0.0)) > 0       # the velocity of eq. (M3)
    if "alpha_covariance" not in params and not kalman:
        # eq. (4)'s alpha_2 follows alpha_1: the covariance averages covariance_ratio
        # times the events the mean does, as in the paper's grid (0.02 / 5e-5), never
        # faster than the default (the paper's face, 2e-4: faster lost the biplane's
        # parts).  With the motion model alpha_1 only caps the Kalman gain of eq. (M3) and
        # alpha_2 keeps the default (the real dot: 0.98 px, against 11.4 with the ratio).
        a2 = min(params["alpha_position"] / lp.covariance_ratio, Params().alpha_covariance)
        params["alpha_covariance"] = float(f"{a2:.3g}")
    stiff = np.array([lp.stiffness_gain * params["alpha_position"] * c.rigidity for c in kept])
    if kept:
        # the spring bound every model meets (springtrack.limits): all stiffnesses scaled
        # down together if a tracker's spring load would exceed it
        stiff = stiff * spring_scale(n, [c.a for c in kept], [c.b for c in kept],
                                     [sum(SPRING_BIT[s] for s in c.kinds) for c in kept],
                                     stiff, mass)
        kind = params.setdefault("energy_kind", "cartesian" if all(
            c.kinds == ("cartesian",) for c in kept) else "euclidean")
        if "energy_scale" not in params and not one_shape:
            # the object's view changed within the window (no similarity of one shape):
            # its own change of shape would read as an occlusion and eq. (22) would pull
            # the trackers back to a shape the object no longer has, so eqs. (21)-(22) are
            # off: s above the number of springs, which no E_ij can exceed (eq. 13:
            # E_ij <= sum E = n_c mean E)
            params["energy_scale"] = float(len(kept) + 1)
        elif "energy_scale" not in params:
            s = energy_scale(spring_energies(rec, kept, stiff, kind, x, y),
                             lp.energy_quantile, Params().energy_scale, lp.energy_scale_max)
            params["energy_scale"] = round(s, 3)
    for c in cands:                       # model order from here on
        c.a, c.b = sorted((int(new_of[c.a]), int(new_of[c.b])))
    pairs = sorted(zip(kept, stiff), key=lambda p: (p[0].a, p[0].b))
    kept = [c for c, _ in pairs]
    conns = [Connection(ids[c.a], ids[c.b], c.kinds, float(k)) for c, k in pairs]
    cands.sort(key=lambda c: (c.a, c.b))
    model = ShapeModel(name, width, height, sorted(trackers, key=lambda t: ids.index(t.id)),
                       conns, params, source="learned")
    model.learned = {"speed_px_s": round(float(np.quantile(v[np.isfinite(v)], SPEED_QUANTILE)), 1)
                     if np.isfinite(v).any() else 0.0,
                     "sizes_per_ms": round(fast, 3)}
    return model, kept, cands, counts[order]


def learn(events, trackers: int | None = None, **kw) -> ShapeModel:
    """The learned :class:`ShapeModel` (see :func:`learn_model` for the arguments)."""
    return learn_model(events, trackers, **kw).model
