"""``hostctl monitor``: a live terminal view redrawn ``rate`` times a second (plain ANSI:
cursor home + clear) - per-tracker position, active/sensitive flags, activity, optional
smoothed velocity; the model instances' states (searching, tracking, lost); mean energy,
event rate, telemetry rate, lost frames, link errors; the device's state, fault
counters and last error."""
from __future__ import annotations

import sys
import time

from springtrack.track import STATE_NAMES, TRACKING_CODE
from springtrack.wire import state_runs

from .record import device_ids
from .smooth import Smoother

HOME_CLEAR = "\x1b[H\x1b[2J"
NOT_FOUND_EXIT = 8          # exit status: a model instance the device has not found


def event_count(stats: dict) -> int | None:
    """The firmware's tracked-event counter, whatever its exact name."""
    for key in ("events_tracked", "tracker.events_valid", "events_decoded", "events"):
        if isinstance(stats.get(key), (int, float)):
            return int(stats[key])
    return None


def status_line(dev, stats: dict) -> str:
    """The device's state and fault counters (STATS), and the last ERROR it sent."""
    last = stats.get("last_error") or (dev.errors[-1].text if dev.errors else "")
    return (f"state {stats.get('state', '?')}   faults {stats.get('supervisor.faults', 0)}   "
            f"non-finite dropped {stats.get('loop.nonfinite_snapshots', 0)}   "
            f"stalls {stats.get('loop.watchdog_stalls', 0)}   errors received "
            f"{dev.counts['errors']}" + (f"   last error: {last[:100]}" if last else ""))


# the device states (STATS ``state``) in which it sends no telemetry, and what to do
SILENT_STATES = {
    "ended": "the device's source has ended (`hostctl record --start` replays it and "
             "records it from its first event)",
    "idle": "the device is not started (hostctl start)",
    "stopped": "the device is stopped (hostctl start)",
    "faulted": "the device is faulted (hostctl stats shows its last error; hostctl reset)",
}
# an instance in one of these states has not been found by the device's acquisition
UNFOUND = ("searching", "not found")


def instance_states(stats: dict) -> dict:
    """Each model instance's state from STATS (``instances.LABEL``): {label: state}."""
    return {k[len("instances."):]: v for k, v in stats.items() if k.startswith("instances.")}


def unfound_line(stats: dict) -> str:
    """What STATS says of the instances the acquisition has not found ('' if none)."""
    lost = {k: v for k, v in instance_states(stats).items() if v in UNFOUND}
    if not lost:
        return ""
    tries = stats.get("kernel.acquire_attempts")
    dropped = stats.get("kernel.acquire_events_dropped")
    return (", ".join(f"model instance {k} {v}" for k, v in lost.items())
            + (f" ({tries} acquisition window(s) tried, {dropped:,} events searched in vain)"
               if isinstance(tries, int) and isinstance(dropped, int) else ""))


def why_silent(stats: dict) -> str:
    """Why a device sends no telemetry, from its STATS."""
    state = stats.get("state")
    why = SILENT_STATES.get(state, f"the device's state is {state!r}")
    found = unfound_line(stats)
    return why + (f"; {found}" if found else "")


def verdict(stats: dict, tracked: bool) -> str:
    """'' when every model instance was found; else what was not, for the exit message:
    an instance ``not found`` (its search budget spent), or still ``searching`` when
    nothing received was tracking (``tracked``: a snapshot had a tracking tracker)."""
    states = instance_states(stats)
    if any(v == "not found" for v in states.values()) or \
            (not tracked and any(v == "searching" for v in states.values())):
        return unfound_line(stats)
    return ""


def instances_line(trackers) -> str:
    """The trackers' instance states as runs: ``state: tracking (trackers 0-25)``."""
    parts, k = [], 0
    for st, count in state_runs(trackers["state"]):
        name = STATE_NAMES[st] if st < len(STATE_NAMES) else f"state {st}"
        parts.append(f"{name.upper() if name != 'tracking' else name} (trackers {k}-{k + count - 1})")
        k += count
    return "state: " + ", ".join(parts)


def render(dev, snap, ids, smooth, rates: dict, stats: dict | None = None) -> str:
    lc = dev.link_counters()
    errors = lc["crc_errors"] + lc["cobs_errors"] + lc["malformed"] + lc["oversize"]
    lines = [f"hostctl monitor  {dev.url}  model {dev.info.get('model', '?')}  "
             f"generation {snap.generation}  t = {snap.t_us / 1e6:.3f} s",
             f"mean energy {snap.mean_energy:.4g}   events {rates.get('events', 0):.0f}/s   "
             f"telemetry {rates.get('telemetry', 0):.0f}/s   lost frames {lc['lost']}   "
             f"link errors {errors}   retries {lc['retries']}   "
             f"firmware tx dropped {lc.get('firmware.tx_dropped', 0)}",
             status_line(dev, stats or {}),
             instances_line(snap.trackers),
             ""]
    head = f"{'tracker':<12}{'x':>9}{'y':>9}  act sens {'activity':>9}"
    if smooth is not None:
        head += f"{'vx':>9}{'vy':>9}"
    lines.append(head)
    st = smooth.state() if smooth is not None else None
    for k, row in enumerate(snap.trackers):
        line = (f"{ids[k]:<12}{row['x']:9.2f}{row['y']:9.2f}  "
                f"{'*' if row['active'] else '.':>3} {'*' if row['sensitive'] else '.':>4} "
                f"{row['activity']:9.1f}")
        if st is not None:
            line += f"{st['vx'][k]:9.1f}{st['vy'][k]:9.1f}"
        lines.append(line)
    return "\n".join(lines)


def monitor(dev, seconds: float | None = None, smooth: bool = False, rate: float = 12.0,
            out=None, view=None) -> int:
    """Redraw the terminal view ``rate`` times a second for ``seconds`` (None: until
    interrupted); every snapshot also goes to ``view`` (a springtrack.view.RerunView)."""
    out = out or sys.stdout
    period = 1.0 / max(rate, 1e-3)
    end = None if seconds is None else time.monotonic() + seconds
    last = None
    ids = []
    smoother = None
    rates: dict = {}
    n_tele, t_rate = 0, time.monotonic()
    tracked = False
    stats = dev.stats()
    ev0 = event_count(stats)
    next_draw = time.monotonic()
    while end is None or time.monotonic() < end:
        for snap in dev.telemetry(seconds=min(period, 0.05)):
            if time.monotonic() >= next_draw and last is not None:
                dev.snapshots.appendleft(snap)          # handle it after this redraw
                break
            n_tele += 1
            tracked = tracked or bool((snap.trackers["state"] == TRACKING_CODE).any())
            if last is None or len(snap.trackers) != len(last.trackers):
                ids = device_ids(dev, len(snap.trackers))
                smoother = Smoother(len(snap.trackers)) if smooth else None
            if smoother is not None:
                smoother.update(snap.t_us, snap.trackers["x"], snap.trackers["y"])
            if view is not None:
                view.telemetry(snap.t_us, snap.trackers, snap.mean_energy)
            last = snap
        now = time.monotonic()
        if now - t_rate >= 0.5:
            stats = dev.stats()
            ev = event_count(stats)
            if ev is not None and ev0 is not None:
                rates["events"] = (ev - ev0) / (now - t_rate)
            rates["telemetry"] = n_tele / (now - t_rate)
            ev0, n_tele, t_rate = ev, 0, now
        if now >= next_draw:
            next_draw = max(next_draw + period, now)     # fixed schedule: no drift
            why = (why_silent(stats) if stats.get("state") != "running"
                   else "the device runs but has sent none yet")
            body = (render(dev, last, ids, smoother, rates, stats) if last is not None
                    else f"hostctl monitor  {dev.url}: waiting for telemetry ({why})\n"
                         + status_line(dev, stats))
            out.write(HOME_CLEAR + body + "\n")
            out.flush()
    missing = verdict(dev.stats(), tracked)
    if missing:
        print(f"hostctl monitor: {missing}", file=sys.stderr)
        return NOT_FOUND_EXIT
    return 0
