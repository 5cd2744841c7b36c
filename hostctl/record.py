"""Recording telemetry to files.

* ``OUT.csv`` - the track CSV schema of ``springtrack track`` (springtrack.track.CSV_HEADER:
  ``t_us,tracker,x,y,sxx,sxy,syy,activity,vx,vy,active,sensitive,state``), so ``springtrack
  score`` reads recordings; the tracker ids are those of the device's model (``hostctl
  get-model``), so ``springtrack render --model`` draws them.  With smoothing, the
  smoothed states go to a sidecar ``OUT.smooth.csv`` (``t_us,tracker,x_s,y_s,vx,vy``) so
  the main file keeps the schema.
* ``OUT.npz`` - arrays ``t_us (T,)``, ``ids (K,)``, ``x, y, sxx, sxy, syy, activity,
  vx, vy, active, sensitive (T, K)``, ``generation, mean_energy, seq, host_time (T,)`` and,
  with smoothing, ``smooth_t_us (T',)``, ``x_s, y_s, vx_s, vy_s (T', K)``.

Values are the telemetry's fixed-point quantities decoded (1/16 px positions etc.,
docs/protocol.md), not the firmware's float state.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from springtrack.track import TRACK_FIELDS, TRACKING_CODE, Track

from .smooth import SMOOTH_FIELDS, smooth_track


def tracker_ids(info: dict, n: int) -> list[str]:
    ids = info.get("trackers")
    if isinstance(ids, list) and len(ids) == n and all(isinstance(i, str) for i in ids):
        return ids
    return [f"t{k:02d}" for k in range(n)]


def device_ids(dev, n: int) -> list[str]:
    """The ids of the ``n`` trackers the device runs now: its model's (MODEL_GET, so a model
    learned or uploaded since the session opened names them as ``hostctl get-model``
    does), else INFO's, else t00, t01, ..."""
    from springtrack.model import ModelError, loads
    from .device import HostctlError
    try:
        ids = [t.id for t in loads(dev.get_model(), "the device's model").trackers]
    except (HostctlError, ModelError, ValueError):
        ids = None
    if ids is not None and len(ids) == n:
        return ids
    return tracker_ids(dev.info, n)


def stack(snaps) -> dict:
    """Snapshots -> arrays; snapshots with a different tracker count than the last one
    (a model swap mid-recording) are dropped and counted in ``dropped``."""
    snaps = list(snaps)
    if not snaps:
        raise ValueError("no telemetry received: is the device started (hostctl start)?")
    n = len(snaps[-1].trackers)
    keep = [s for s in snaps if len(s.trackers) == n]
    tr = np.stack([s.trackers for s in keep])
    out = {f: tr[f] for f in TRACK_FIELDS}
    out.update(t_us=np.array([s.t_us for s in keep], np.int64),
               generation=np.array([s.generation for s in keep], np.int64),
               mean_energy=np.array([s.mean_energy for s in keep], np.float64),
               seq=np.array([s.seq for s in keep], np.int64),
               host_time=np.array([s.host_time for s in keep], np.float64),
               dropped=len(snaps) - len(keep))
    return out


def to_track(arrs: dict, ids) -> Track:
    """A Track from a recording's arrays (one saved without velocities reads as still)."""
    still = np.zeros(np.shape(arrs["x"]))
    return Track(arrs["t_us"], list(ids),
                 **{f: arrs[f] if f in arrs else still for f in TRACK_FIELDS})


def save(path, snaps, info: dict, smooth: dict | None = None, ids=None) -> dict:
    """Write a recording; ``smooth`` is None or the Smoother keyword arguments; ``ids``
    a function of the tracker count giving their ids (default: INFO's ``trackers``).
    Returns a summary (rows, trackers, files, tracked: a row had a tracking tracker)."""
    path = Path(path)
    arrs = stack(snaps)
    ids = (ids or (lambda n: tracker_ids(info, n)))(arrs["x"].shape[1])
    sm = smooth_track(arrs["t_us"], arrs["x"], arrs["y"], **smooth) if smooth is not None else None
    files = [str(path)]
    if path.suffix == ".npz":
        extra = {}
        if sm is not None:
            # the smoothed velocities as vx_s, vy_s: vx, vy are the tracker's own (eq. M7)
            extra = {"smooth_t_us": sm["t_us"],
                     **{k if k.endswith("_s") else k + "_s": sm[k] for k in SMOOTH_FIELDS}}
        np.savez_compressed(path, ids=np.array(ids), **{k: v for k, v in arrs.items()
                                                        if k != "dropped"}, **extra)
    elif path.suffix == ".csv":
        to_track(arrs, ids).to_csv(path)
        if sm is not None:
            side = path.with_suffix(".smooth.csv")
            _smooth_csv(side, sm, ids)
            files.append(str(side))
    else:
        raise ValueError(f"{path}: unknown recording format {path.suffix!r}; use .csv or .npz")
    return dict(snapshots=len(arrs["t_us"]), trackers=len(ids), dropped=arrs["dropped"],
                files=files, tracked=bool((arrs["state"] == TRACKING_CODE).any()))


def _smooth_csv(path, sm: dict, ids) -> None:
    k = len(ids)
    with open(path, "w") as f:
        f.write("t_us,tracker,x_s,y_s,vx,vy\n")
        t = np.repeat(sm["t_us"], k).tolist()
        names = ids * len(sm["t_us"])
        cols = [sm[c].ravel().tolist() for c in SMOOTH_FIELDS]
        f.writelines(f"{a},{b},{c:.4f},{d:.4f},{e:.4f},{g:.4f}\n"
                     for a, b, c, d, e, g in zip(t, names, *cols))
