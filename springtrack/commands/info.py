"""``springtrack info FILE``: format, geometry, header, event count, time span, mean and
peak event rate (per 10 ms bin), decode anomalies and recording quirks (coarse timestamp
ticks, events in row order or unsorted, full-frame bursts: springtrack.prep.QuirkScan,
each with what to do) of an event file."""
from __future__ import annotations

import json
from collections import Counter
from datetime import datetime, timedelta, timezone

import numpy as np

from ..io.stats import CORRUPT_SHARE

BIN_US = 10_000
# timestamps from here on are taken for Unix-epoch microseconds (AEDAT 4 keeps them so):
# 10**15 us is 2001-09-09, 4 * 10**15 us is 2096
EPOCH_US = (10**15, 4 * 10**15)
WORD_UNIT = {"es": "bytes", "aedat4": "packets", "dv": "packets", "dv-camera": "packets",
             "udp": "datagrams"}
# 10 ms bins kept open for counting: older ones are closed (their count weighed for the
# peak) once twice as many are open, so memory is constant however long the recording; an
# event more than BINS_OPEN bins (10 s) back in time starts its bin's count anew
BINS_OPEN = 1024


def add_arguments(p):
    p.add_argument("file", help="event file (.raw EVT 2.0/2.1/3.0, .es, .dat, .aedat4, .ccam, "
                                ".npy, .csv), or - for an event stream (e.g. RAW) on standard input")
    p.add_argument("--format", help="force the format (needed only for headerless files)")
    p.add_argument("--chunk", type=int, default=1 << 20, help="bytes decoded per step")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def summarize(path, format=None, chunk=1 << 20) -> dict:
    """Stream the file once; return the facts ``info`` prints."""
    from .. import io
    from ..prep import QuirkScan
    reader = io.open(path, format=format)
    n, t_min, t_max, p_on = 0, None, None, 0
    bins = Counter()
    peak_bin, peak = None, 0
    w, h = reader.width, reader.height
    if not (w and h) and reader.format in ("npy", "csv"):      # in memory: their extent
        ev = reader.read()
        w = int(ev["x"].max()) + 1 if len(ev) else 1
        h = int(ev["y"].max()) + 1 if len(ev) else 1
    scan = QuirkScan(w, h)
    origin = None                # the bins of the peak rate start at the first event
    for ev in reader.chunks(chunk):
        scan.feed(ev)
        t = ev["t"]
        if not len(t):
            continue
        n += len(ev)
        p_on += int(np.count_nonzero(ev["p"]))
        lo, hi = int(t.min()), int(t.max())
        t_min = lo if t_min is None else min(t_min, lo)
        t_max = hi if t_max is None else max(t_max, hi)
        origin = int(t[0]) if origin is None else origin
        b, c = np.unique((t - origin) // BIN_US, return_counts=True)
        bins.update(dict(zip(b.tolist(), c.tolist())))
        if len(bins) > 2 * BINS_OPEN:
            peak_bin, peak = _close_bins(bins, max(bins) - BINS_OPEN, peak_bin, peak)
    span = (t_max - t_min) if n else 0
    peak_bin, peak = _close_bins(bins, max(bins) if bins else None, peak_bin, peak)
    peak_bin, peak = _peak(bins, peak_bin, peak, origin, t_max)     # with the last bin
    s = reader.stats
    quirks = scan.finish()
    return {
        "file": str(path), "format": reader.format,
        "event_type": reader.event_type, "width": reader.width, "height": reader.height,
        "header": reader.header, "events": n, "on_events": p_on,
        "t_first_us": t_min, "t_last_us": t_max, "span_us": span,
        "mean_rate_ev_s": (n / (span * 1e-6)) if span > 0 else None,
        "peak_rate_ev_s": peak,
        "peak_bin_start_us": None if peak_bin is None else origin + peak_bin * BIN_US,
        "t_epoch_utc": (_utc(t_min), _utc(t_max)) if n and _is_epoch(t_min) else None,
        "words": s.words, "pending_bytes": s.pending_bytes,
        "anomalies": s.anomalies, "info": s.info,
        "undecodable": bool(getattr(s, "undecodable", False)),
        "quirks": {
            "tick_us": quirks.tick_us, "time_backwards": quirks.time_backwards,
            "row_steps": quirks.row_steps, "row_steps_down": quirks.row_steps_down,
            "row_steps_up": quirks.row_steps_up, "row_ordered": quirks.row_ordered,
            "bursts_checked": quirks.bursts_checked, "burst_bins": quirks.burst_bins,
            "burst_events": quirks.burst_events, "burst_at_us": quirks.burst_at_us,
            "findings": [{"found": f, "do": d} for f, d in quirks.findings()]},
    }


def _close_bins(bins: Counter, before, peak_bin, peak):
    """Close the bins older than ``before`` (None: all): (peak bin, its count) so far."""
    for b in [b for b in bins if before is None or b < before]:
        c = bins.pop(b)
        if c > peak:
            peak_bin, peak = b, c
    return peak_bin, peak


def _peak(last: Counter, peak_bin, peak, origin, t_max) -> tuple:
    """(bin, events/s) of the densest BIN_US bin from the first event: the closed, whole
    bins' counts over a bin; the ``last`` one's over the time it covers up to the last
    event, counted when that is half a bin or more, or when it is the only bin (its rate is
    then the mean's, over the events' span)."""
    rate = peak / (BIN_US * 1e-6)
    for b, c in last.items():
        start = origin + b * BIN_US
        if peak_bin is None:                 # the only bin
            return b, c / ((t_max - start) * 1e-6) if t_max > start else 0.0
        cover = t_max + 1 - start
        if cover >= BIN_US // 2 and c / (cover * 1e-6) > rate:
            peak_bin, rate = b, c / (cover * 1e-6)
    return peak_bin, rate


def _is_epoch(t_us: int) -> bool:
    return EPOCH_US[0] <= t_us < EPOCH_US[1]


def _utc(t_us: int) -> str:
    t = datetime.fromtimestamp(t_us // 1_000_000, timezone.utc)
    return (t + timedelta(microseconds=t_us % 1_000_000)).strftime("%Y-%m-%d %H:%M:%S.%f UTC")


def run(args) -> int:
    facts = summarize(args.file, args.format, args.chunk)
    if args.json:
        print(json.dumps(facts, indent=1))
        return 0
    geom = (f"{facts['width']}x{facts['height']}" if facts["width"] else "unknown")
    src = facts["header"].get("geometry_source")
    print(f"file      {facts['file']}")
    print(f"format    {facts['format']}"
          + (f" ({facts['event_type']})" if facts["event_type"] else ""))
    print(f"geometry  {geom}" + (f" (from {src})" if src else ""))
    for k, v in facts["header"].items():
        if k != "geometry_source":
            print(f"header    {k}: {v}")
    print(f"events    {facts['events']:,} ({facts['on_events']:,} ON)")
    if facts["events"]:
        print(f"time      {facts['t_first_us']:,} .. {facts['t_last_us']:,} us "
              f"(span {facts['span_us'] / 1e6:.6f} s)")
        if facts["t_epoch_utc"]:
            print(f"          = {facts['t_epoch_utc'][0]} .. {facts['t_epoch_utc'][1]} "
                  "(Unix-epoch us, kept as recorded)")
            print(f"          = 0 .. {facts['span_us']:,} us from the first event")
        mean = facts["mean_rate_ev_s"]
        print(f"rate      mean {mean / 1e6:.3f} Mev/s" if mean else "rate      mean n/a",
              end="")
        short = facts["span_us"] < BIN_US
        print(f", peak {facts['peak_rate_ev_s'] / 1e6:.3f} Mev/s "
              + ("(the recording is shorter than a 10 ms bin)" if short else
                 f"(10 ms bin from the first event, at {facts['peak_bin_start_us']:,} us)"))
    unit = WORD_UNIT.get(facts["format"], "words")
    print(f"decoded   {facts['words']:,} {unit}, {facts['pending_bytes']} bytes pending")
    bad = {k: v for k, v in facts["anomalies"].items() if v}
    print("anomalies " + (", ".join(f"{k} {v:,}" for k, v in bad.items()) or "none"))
    if facts["undecodable"]:
        print(f"doubtful  over {CORRUPT_SHARE:.0%} of the {unit} are corrupt: not a file "
              f"of format {facts['format']}, or badly damaged; track, learn and render "
              f"refuse it (--format FORMAT reads it as another format)")
    if facts["info"]:
        print("counts    " + ", ".join(f"{k} {v:,}" for k, v in facts["info"].items()))
    q = facts["quirks"]
    if facts["events"] and not q["findings"]:
        print(f"quirks    none (timestamps in {q['tick_us']} us steps, in order, no "
              f"full-frame burst)")
    for f in q["findings"]:
        print(f"quirk     {f['found']}")
        print(f"  do      {f['do']}")
    return 0
