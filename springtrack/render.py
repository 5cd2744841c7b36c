"""Overlay rendering and plots: events with the trackers drawn over them (paper Figs. 10,
13, 18, 19) and curves of energy, error and compute load (Figs. 20-23).

Rendering uses matplotlib (Agg) with one persistent figure whose artists are updated per
frame.  The events are drawn as a uint8 picture already at the output's pixel size and
put under the figure's lines and text pixel for pixel (:func:`composited`), so a frame
costs a few bytes per pixel, not the ~90 of matplotlib's float resampling of an image
(330 MB for a 1280 x 720 sensor at scale 2).  Frames go to their writer one by one as they are drawn (GIF: :class:`GifStream`;
MP4 through imageio-ffmpeg; PNGs), so memory does not grow with the number of frames.
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from .model import ShapeModel
from .track import Track

ACTIVE = "#1a9850"        # green: active and sensitive
INACTIVE = "#222222"      # black: sensitive but not active
INSENSITIVE = "#f46d43"   # orange, dashed: insensitive (eq. 21)
LOST = "#9e9e9e"          # grey, dotted: the instance is lost (springtrack.acquisition.loss)
SPRING = "#888888"        # grey line: a spring between two trackers
ACQUIRED = "#7b3294"      # purple x: where an acquisition placed an instance
TRUTH = "#ffd92f"
ON_RGB = np.array([0.85, 0.15, 0.15])
OFF_RGB = np.array([0.15, 0.35, 0.9])
BG = 0.96
# the legend of every picture of a track (these figures, the live view): label, colour
LEGEND = (("active (2σ)", ACTIVE), ("inactive", INACTIVE), ("insensitive", INSENSITIVE),
          ("lost", LOST), ("spring", SPRING), ("ON", ON_RGB), ("OFF", OFF_RGB))
LEGEND_STYLE = {"active (2σ)": {"lw": 2}, "inactive": {"lw": 2},
                "insensitive": {"lw": 2, "ls": "--"}, "lost": {"lw": 2, "ls": ":"},
                "spring": {"lw": 1}, "ON": {"marker": "s", "ls": ""},
                "OFF": {"marker": "s", "ls": ""}}


def _mpl():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


class EventCounts:
    """ON and all events per pixel of a ``width`` x ``height`` sensor, added chunk by chunk
    (memory: the sensor's pixels, however many events); :meth:`image` draws them."""

    def __init__(self, width: int, height: int):
        self.width, self.height = width, height
        self.on = np.zeros(width * height, np.int64)
        self.all = np.zeros(width * height, np.int64)

    def add(self, ev: np.ndarray) -> "EventCounts":
        w, h = self.width, self.height
        ev = ev[(ev["x"] < w) & (ev["y"] < h)]
        pix = ev["y"].astype(np.int64) * w + ev["x"]
        self.on += np.bincount(pix[ev["p"] > 0], minlength=w * h)
        self.all += np.bincount(pix, minlength=w * h)
        return self

    def image(self) -> np.ndarray:
        """RGB uint8 (height, width, 3) on a light background: each pixel with events is ON
        red and OFF blue mixed in the proportion of its ON and OFF events (purple: as many
        of each), so neither polarity hides the other."""
        img = np.full((self.height * self.width, 3), round(BG * 255), np.uint8)
        hit = self.all > 0
        frac = (self.on[hit] / self.all[hit])[:, None]
        img[hit] = np.rint(255 * (frac * ON_RGB + (1 - frac) * OFF_RGB))
        return img.reshape(self.height, self.width, 3)


def event_image(ev: np.ndarray, width: int, height: int) -> np.ndarray:
    """The events' picture (:meth:`EventCounts.image`), one pixel per sensor pixel."""
    return EventCounts(width, height).add(ev).image()


COMPOSITE_ROWS = 64          # rows of a frame mixed at a time


def composited(fig, img: np.ndarray, x0: int, y0: int) -> np.ndarray:
    """The figure drawn (its background transparent) over a white page with ``img`` (uint8
    RGB) at ``x0`` px from the left, ``y0`` px from the bottom: RGB uint8 (H, W, 3).  Agg's
    buffer is straight RGBA: out = a fg + (1 - a) bg, in integers, a band of rows at a time
    (no temporary larger than a band)."""
    fig.canvas.draw()
    fg = np.asarray(fig.canvas.buffer_rgba())
    hh, ww = fg.shape[:2]
    out = np.full((hh, ww, 3), 255, np.uint8)
    top = hh - y0 - img.shape[0]
    r0, c0 = max(top, 0), max(x0, 0)
    r1, c1 = min(top + img.shape[0], hh), min(x0 + img.shape[1], ww)
    out[r0:r1, c0:c1] = img[r0 - top:r1 - top, c0 - x0:c1 - x0]
    for r in range(0, hh, COMPOSITE_ROWS):
        band = slice(r, r + COMPOSITE_ROWS)
        a = fg[band, :, 3:].astype(np.uint16)
        mixed = fg[band, :, :3] * a
        mixed += out[band] * (255 - a)
        mixed += 127
        mixed //= 255
        out[band] = mixed
    return out


def upscaled(img: np.ndarray, scale: float) -> np.ndarray:
    """``img`` (h, w, 3) at round(h scale) x round(w scale) px, each output pixel the
    sensor pixel it lies in (nearest neighbour)."""
    h, w = img.shape[:2]
    rows = np.minimum((np.arange(round(h * scale)) / scale).astype(np.intp), h - 1)
    cols = np.minimum((np.arange(round(w * scale)) / scale).astype(np.intp), w - 1)
    return img[rows[:, None], cols[None, :]]


class Header:
    """The band above an overlay frame, sized so its text and legend fit the picture's
    width at any size: ``width_px`` wide; the text in a monospace font that fits
    ``MIN_LINE_CHARS`` characters per line (wrapped to as many lines as
    ``HEADER_CHARS`` needs), the legend in as many columns as fit, in rows below it."""

    HEADER_CHARS = 130           # the longest header text drawn (title, times, states)
    MIN_LINE_CHARS = 44
    CHAR_EM = 0.6                # a monospace glyph's advance, in ems
    LEGEND_ENTRY_EMS = 8.5       # a legend entry: its handle, gap and label, in ems

    def __init__(self, width_px: float, scale: float):
        px_per_pt = 100 / 72                                  # at 100 dpi
        self.fs = min(9 * scale / 2, width_px / (self.MIN_LINE_CHARS * self.CHAR_EM * px_per_pt))
        self.legend_fs = min(6.5 * scale / 2, self.fs)
        self.width_px = width_px
        # Agg draws hinted glyphs a whole number of pixels apart (9 pt at 100 dpi: 8 px, not
        # 7.5): a line holds as many characters as fit at the advance rounded up
        advance_px = math.ceil(self.CHAR_EM * self.fs * px_per_pt)
        self.line_chars = max(1, int(width_px // advance_px) - 1)
        self.lines = -(-self.HEADER_CHARS // self.line_chars)
        self.pad = 2.0
        line_px = 1.25 * self.fs * px_per_pt
        self.legend_top = self.pad + self.lines * line_px
        self._leg_row_px = 1.45 * self.legend_fs * px_per_pt
        self._entry_px = self.LEGEND_ENTRY_EMS * self.legend_fs * px_per_pt
        self.height = self.legend_top + self._leg_row_px * -(-7 // self.legend_columns(7)) + 2 * self.pad

    def legend_columns(self, entries: int) -> int:
        return max(1, min(entries, int(self.width_px // self._entry_px)))

    def wrap(self, text: str) -> str:
        import textwrap
        return "\n".join(textwrap.wrap(text, self.line_chars)[:self.lines])


def ellipse_xy(x, y, sxx, sxy, syy, nsig=2.0, n=40):
    """Points of the nsig-sigma ellipse of a 2-D Gaussian: (xs, ys), n each."""
    pts = ellipses_xy([x], [y], [sxx], [sxy], [syy], nsig, n)[0]
    return pts[:, 0], pts[:, 1]


def ellipses_xy(x, y, sxx, sxy, syy, nsig=2.0, n=40) -> np.ndarray:
    """Points of the nsig-sigma ellipses of K 2-D Gaussians (arrays of K): (K, n, 2)."""
    cov = np.stack([np.stack([sxx, sxy], -1), np.stack([sxy, syy], -1)], -2)    # (K, 2, 2)
    vals, vecs = np.linalg.eigh(cov.astype(np.float64))
    a = np.linspace(0, 2 * math.pi, n)
    circ = np.stack([np.cos(a), np.sin(a)])[None] * (nsig * np.sqrt(np.maximum(vals, 0)))[..., None]
    pts = vecs @ circ                                                            # (K, 2, n)
    return np.stack([np.asarray(x, np.float64)[:, None] + pts[:, 0],
                     np.asarray(y, np.float64)[:, None] + pts[:, 1]], -1)


def drawn(models):
    """(width, height, ids, links, instance of each tracker, labels) of a model or a
    ``springtrack.instances.ModelSet``."""
    from .instances import ModelSet
    mset = models if isinstance(models, ModelSet) else ModelSet([models])
    links = []
    for inst in mset:
        idx = {t: inst.t0 + i for i, t in enumerate(inst.model.ids)}
        links += [(idx[c.a], idx[c.b]) for c in inst.model.connections]
    return (mset.width, mset.height, list(mset.ids), links, mset.instance_of(),
            [i.label for i in mset])


class OverlayRenderer:
    """One figure, updated per frame. ``frame(t_us, events, state_row)`` returns RGB uint8.
    ``model``: a ShapeModel or a ModelSet (several instances, each drawn by its state:
    a lost instance grey and dotted, one not found yet not drawn)."""

    def __init__(self, model, scale: float = 2.0, title: str = ""):
        plt = _mpl()
        self.plt = plt
        w, h, self.ids, self.links, self.inst, self.labels = drawn(model)
        head = Header(w * scale, scale)
        hpx = h * scale + head.height
        self.head = head
        self.fig = plt.figure(figsize=(w * scale / 100, hpx / 100), dpi=100)
        self.ax = self.fig.add_axes([0, 0, 1, h * scale / hpx])
        self.ax.set_xlim(-0.5, w - 0.5)
        self.ax.set_ylim(h - 0.5, -0.5)
        self.ax.set_axis_off()
        self.fig.patch.set_alpha(0)   # the events' picture goes under it (composited)
        self.scale = scale
        self.width, self.height = w, h
        self.link_lines = [self.ax.plot([], [], "-", color=SPRING, lw=0.8)[0] for _ in self.links]
        self.ell = [self.ax.plot([], [], "-", lw=1.4)[0] for _ in self.ids]
        self.truth_pts = self.ax.plot([], [], "+", color=TRUTH, ms=7, mew=1.5)[0]
        self.acq_pts = self.ax.plot([], [], "x", color=ACQUIRED, ms=6, mew=1.5)[0]
        self.text = self.fig.text(0.01, 1 - head.pad / hpx, "", fontsize=head.fs,
                                  family="monospace", va="top", ha="left")
        from matplotlib.lines import Line2D
        handles = [Line2D([], [], color=colour, label=label, **LEGEND_STYLE[label])
                   for label, colour in LEGEND]
        self.fig.legend(handles=handles, loc="upper left", ncol=head.legend_columns(len(handles)),
                        bbox_to_anchor=(0.0, 1 - head.legend_top / hpx),
                        fontsize=head.legend_fs, frameon=False, handlelength=1.2,
                        columnspacing=0.8, borderaxespad=0.2, borderpad=0.1, labelspacing=0.2)
        self.title = title

    def frame(self, t_us: int, events: np.ndarray, st: dict, truth_xy=None, window_us=10_000,
              acquired_xy=None, origin_us: int = 0):
        """``acquired_xy`` (K, 2): where acquisitions placed trackers (shown as x);
        ``origin_us``: the recording's first event, from which the header counts time (the
        recording's own clock at its end)."""
        from .instances import LOST as LOST_CODE, TRACKING
        from .track import STATE_NAMES
        state = st.get("state")
        state = np.full(len(self.ids), 1) if state is None else np.asarray(state)
        img = upscaled(event_image(events, self.width, self.height), self.scale)
        placed = (state == TRACKING) | (state == LOST_CODE)     # searched-for: not drawn
        for k, (i, j) in enumerate(self.links):
            shown = placed[i]
            self.link_lines[k].set_data([st["x"][i], st["x"][j]] if shown else [],
                                        [st["y"][i], st["y"][j]] if shown else [])
        for i, line in enumerate(self.ell):
            if not placed[i]:
                line.set_data([], [])
                continue
            ex, ey = ellipse_xy(st["x"][i], st["y"][i], st["sxx"][i], st["sxy"][i], st["syy"][i])
            line.set_data(ex, ey)
            if state[i] == LOST_CODE:
                line.set_color(LOST)
                line.set_linestyle(":")
            elif not st["sensitive"][i]:
                line.set_color(INSENSITIVE)
                line.set_linestyle("--")
            else:
                line.set_color(ACTIVE if st["active"][i] else INACTIVE)
                line.set_linestyle("-")
        if truth_xy is not None:
            self.truth_pts.set_data(truth_xy[:, 0], truth_xy[:, 1])
        if acquired_xy is not None and len(acquired_xy):
            self.acq_pts.set_data(acquired_xy[:, 0], acquired_xy[:, 1])
        else:
            self.acq_pts.set_data([], [])
        n_act = int(np.sum(st["active"]))
        gone = [f"{lab} {STATE_NAMES[state[self.inst == g][0]]}"
                for g, lab in enumerate(self.labels) if state[self.inst == g][0] != TRACKING]
        self.text.set_text(self.head.wrap(
            f"{self.title}  t = {(t_us - origin_us) / 1e6:.3f} s  events in last "
            f"{window_us / 1000:g} ms: {len(events)}  active {n_act}/{len(self.ids)}"
            + (f"  {', '.join(gone)}" if gone else "")
            + (f"  (clock {t_us / 1e6:.6f} s)" if origin_us else "")))
        return composited(self.fig, img, 0, 0)

    def close(self):
        self.plt.close(self.fig)


def _state_at(track: Track, k: int) -> dict:
    return {f: getattr(track, f)[k]
            for f in ("x", "y", "sxx", "sxy", "syy", "active", "sensitive", "state")}


def _acquired_at(acquisitions, t, window_us):
    """The (x, y) of the placements made in the ``window_us`` before ``t``."""
    if not acquisitions:
        return None
    near = [xy for ta, xy in acquisitions if t - window_us <= ta <= t]
    return np.concatenate(near) if near else None


def frame_rows(t_us: np.ndarray, window_us: int, every_us: int, one: bool,
               max_frames: int) -> np.ndarray:
    """The track rows (indices into the sample times ``t_us``) to draw: one every
    ``every_us`` from the first sample plus ``window_us`` (the first full window) to the
    last, or only the middle one (``one``); ValueError above ``max_frames``."""
    first, last = int(t_us[0]) + window_us, int(t_us[-1]) + 1
    count = max(0, -(-(last - first) // every_us))        # counted before any allocation
    if one:                                               # the middle frame only
        times = np.array([first + every_us * (count // 2)]) if count else t_us[-1:]
    elif count > max_frames:
        raise ValueError(f"render: {count} frames exceed --max-frames {max_frames}; "
                         f"raise --every-us or --max-frames")
    else:
        times = np.arange(first, last, every_us) if count else t_us[-1:]
    return np.clip(np.searchsorted(t_us, times), 0, len(t_us) - 1)


def render(events: np.ndarray, model, track: Track, out, window_us: int = 10_000,
           every_us: int | None = None, truth=None, title: str = "", progress: bool = True,
           max_frames: int = 2000, scale: float = 2.0, acquisitions=None,
           origin_us: int | None = None) -> int:
    """Render frames at track sample times spaced by ``every_us`` (default ``window_us``).
    ``model``: a ShapeModel or a ModelSet (the track's instances); ``acquisitions``:
    [(t_us, (K, 2) positions)] of placements by the acquisition, each drawn for one
    window after it.  ``out``: .gif/.mp4 (video), .png (one frame: the middle one) or a
    directory (PNGs).  Frame times count from ``origin_us`` (default: the first event),
    the recording's clock at the header's end.  Returns the number of frames written."""
    if origin_us is None:
        origin_us = int(events["t"][0]) if len(events) else int(track.t_us[0]) if len(track) else 0
    out = Path(out)
    every_us = every_us or window_us
    if len(track) == 0:
        raise ValueError("render: the track has no samples (is the event file empty?)")
    rows = frame_rows(track.t_us, window_us, every_us, out.suffix == ".png", max_frames)
    # each frame ends at its sample's time, so the events drawn are those up to the state
    # drawn (a sample holds the state after every event before its time): a fast part's
    # tracker sits on its events, not one sample period ahead of them
    times = track.t_us[rows]
    r = OverlayRenderer(model, scale=scale, title=title)
    t_ev = events["t"]
    frames = []
    writer = None
    try:
        if out.suffix == ".gif":
            writer = GifStream(out, every_us / 1000.0)
        elif out.suffix == ".mp4":
            try:
                import imageio.v2 as iio
            except ImportError:
                raise ValueError(f"{out}: writing {out.suffix} needs imageio: pip install "
                                 f"'springtrack[plots]', or write a .gif or .png") from None
            writer = iio.get_writer(out, fps=max(1, min(50, int(round(1e6 / every_us)))))
        elif out.suffix != ".png":
            out.mkdir(parents=True, exist_ok=True)
        for n, (t, row) in enumerate(zip(times, rows)):
            lo, hi = np.searchsorted(t_ev, [t - window_us, t])
            txy = _truth_xy(truth, r.ids, t) if truth is not None else None
            img = r.frame(int(t), events[lo:hi], _state_at(track, row), txy, window_us,
                          _acquired_at(acquisitions, t, every_us), origin_us)
            if writer is not None:
                writer.append_data(img)
            elif out.suffix == ".png":
                _save_png(out, img)
            else:
                _save_png(out / f"frame_{n:05d}.png", img)
            frames.append(n)
            if progress and sys.stderr.isatty():
                sys.stderr.write(f"\rrender [{'#' * int(30 * (n + 1) / len(times)):<30}] "
                                 f"{n + 1}/{len(times)} frames")
                sys.stderr.flush()
    finally:
        if writer is not None:
            writer.close()
        r.close()
        if progress and sys.stderr.isatty():
            sys.stderr.write("\n")
    return len(frames)


class GifStream:
    """An animated GIF written frame by frame as frames come, so memory holds one frame
    (imageio's Pillow writer keeps every frame until it closes: 2,000 frames of a 1280 x 720
    sensor at scale 2 would be 23 GB).  Each frame is reduced to its own adaptive 256-colour
    palette (as Pillow's GIF writer does with RGB), the first one's the global table, the
    others' local; after the first, a frame is written as the box of pixels that changed,
    laid over the last (disposal 1); it loops forever; ``duration_ms`` per frame (stored in
    1/100 s)."""

    def __init__(self, path, duration_ms: float):
        self.file = open(path, "wb")
        self.duration = duration_ms
        self.frames = 0
        self.prev = None              # the last frame: the next one is written as a change

    def append_data(self, img: np.ndarray) -> None:
        from PIL import GifImagePlugin, Image
        x0, y0 = 0, 0
        if self.prev is not None:          # only the box of pixels that changed (kept below)
            changed = np.any(img != self.prev, axis=2)
            rows, cols = np.flatnonzero(changed.any(1)), np.flatnonzero(changed.any(0))
            if len(rows):
                y0, x0 = int(rows[0]), int(cols[0])
                part = img[y0:int(rows[-1]) + 1, x0:int(cols[-1]) + 1]
            else:
                part = img[:1, :1]
        else:
            part = img
        self.prev = img
        frame = Image.fromarray(np.ascontiguousarray(part)).convert(
            "P", palette=Image.Palette.ADAPTIVE)
        if not self.frames:
            header, _ = GifImagePlugin.getheader(frame, info={"loop": 0,
                                                              "duration": self.duration})
            self.file.write(b"".join(header))
        self.file.write(b"".join(GifImagePlugin.getdata(
            frame, (x0, y0), duration=self.duration, include_color_table=self.frames > 0,
            disposal=1)))
        self.frames += 1

    def close(self) -> None:
        if not self.file.closed:
            self.file.write(b";")                  # the GIF trailer
            self.file.close()


def _save_png(path, img):
    """One raster picture (PNG, or what its suffix names), through matplotlib (which render
    needs anyway): no imageio for pictures."""
    from matplotlib.image import imsave
    imsave(path, img)


def _truth_xy(truth, ids, t):
    """Truth positions (K', 2) of the parts ``ids`` nearest in time to t."""
    k = int(np.clip(np.searchsorted(truth.t_us, t), 0, len(truth.t_us) - 1))
    cols = [truth.ids.index(i) for i in ids if i in truth.ids]
    return truth.xy[k, cols]


# ---- plots -------------------------------------------------------------------------
def plot_energies(track: Track, out, title: str = "") -> None:
    """Fig. 21 style: total energy of each kind over time as % of its maximum."""
    plt = _mpl()
    fig, ax = plt.subplots(figsize=(8, 3))
    t = track.t_us / 1e6
    for q, name in enumerate(("euclidean", "torsional", "cartesian")):
        e = track.energy[:, q]
        if np.nanmax(e) > 0:
            ax.plot(t, 100 * e / np.nanmax(e), lw=1, label=name)
    ax.set_xlabel("event time (s)")
    ax.set_ylabel("mean energy (% of max)")
    ax.set_title(title or "Elastic energy (Fig. 21)")
    ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def plot_error(t_us, pct, out, title: str = "") -> None:
    """Fig. 20 style: tracking error over time as % of the object's length."""
    plt = _mpl()
    fig, ax = plt.subplots(figsize=(8, 3))
    t = np.asarray(t_us) / 1e6
    ax.plot(t, pct, lw=1, color="#3288bd")
    m = float(np.nanmean(pct))
    ax.axhline(m, color="#d53e4f", lw=1.2, label=f"temporal mean {m:.2f} %")
    ax.set_xlabel("event time (s)")
    ax.set_ylabel("error (% of length)")
    ax.set_title(title or "Tracking error (Fig. 20)")
    ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def plot_load(bin_t_us, events_per_bin, proc_us_per_bin, out, bin_us: int = 10_000,
              title: str = "") -> None:
    """Figs. 22-23 style: compute time and events per bin, and their ratio (µs/event)."""
    plt = _mpl()
    fig, axes = plt.subplots(3, 1, figsize=(8, 6), sharex=True)
    t = np.asarray(bin_t_us) / 1e6
    ev = np.asarray(events_per_bin, float)
    pu = np.asarray(proc_us_per_bin, float)
    axes[0].plot(t, pu / 1000, lw=1)
    axes[0].axhline(bin_us / 1000, color="#d53e4f", lw=1, label="real time")
    axes[0].set_ylabel(f"compute per\n{bin_us / 1000:g} ms (ms)")
    axes[0].legend(loc="upper right")
    axes[1].plot(t, ev, lw=1, color="#5e4fa2")
    axes[1].set_ylabel(f"events per\n{bin_us / 1000:g} ms")
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(ev > 0, pu / ev, np.nan)
    axes[2].plot(t, ratio, lw=1, color="#66c2a5")
    axes[2].axhline(np.nanmean(ratio), color="#d53e4f", lw=1,
                    label=f"mean {np.nanmean(ratio) * 1000:.1f} ns/event")
    axes[2].set_ylabel("µs / event")
    axes[2].set_xlabel("event time (s)")
    axes[2].legend(loc="upper right")
    axes[0].set_title(title or "Compute load (Figs. 22-23)")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def plot_model(model: ShapeModel, events: np.ndarray, out, title: str = "",
               scale: float = 2.0) -> None:
    """A model over events (e.g. a learned one at the end of its window): 2-sigma ellipses
    with their ids, springs as lines (solid: euclidean+torsional, dashed: cartesian)."""
    plt = _mpl()
    w, h = model.width, model.height
    fig = plt.figure(figsize=(w * scale / 100, (h + 28) * scale / 100), dpi=100)
    ax = fig.add_axes([0, 0, 1, h / (h + 28)])
    ax.imshow(event_image(events, w, h), interpolation="nearest")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_axis_off()
    at = {t.id: t for t in model.trackers}
    for c in model.connections:
        a, b = at[c.a], at[c.b]
        ax.plot([a.x, b.x], [a.y, b.y], "--" if "cartesian" in c.springs else "-",
                color="#555555", lw=0.9)
    for t in model.trackers:
        ex, ey = ellipse_xy(t.x, t.y, *t.sigma)
        ax.plot(ex, ey, "-", color=ACTIVE, lw=1.3)
        ax.text(t.x, t.y, t.id, fontsize=5 * scale / 2, ha="center", va="center")
    fig.text(0.01, 1 - 14 / (h + 28), title or model.name, fontsize=8 * scale / 2,
             family="monospace", va="center")
    fig.savefig(out, dpi=100)
    plt.close(fig)


RASTER = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp")   # composited pictures
GRID_STEPS = (5, 10, 20, 25, 50, 100, 200, 250, 500)      # px between labelled grid lines


def grid_step(size: int, lines: int = 16) -> int:
    """A round grid spacing (px) giving at most ``lines`` labelled lines over ``size`` px."""
    return next((s for s in GRID_STEPS if size / s <= lines), GRID_STEPS[-1])


def plot_events(events: np.ndarray | None, width: int, height: int, out, title: str = "",
                scale: float = 2.0, grid: int | None = None, image=None) -> tuple:
    """The events alone on the sensor (ON red, OFF blue: each pixel shows its last event),
    with pixel axes and a grid (labelled lines every ``grid`` px, default at most 16 across,
    minor lines every fifth of that), so positions for a model can be read off it.  ``out``:
    any still image matplotlib writes (.png, .svg, .pdf, ...).  ``image``: the events'
    picture already drawn (:meth:`EventCounts.image`) instead of ``events``.  Returns where the sensor
    lies in the picture: (left, top, right, bottom) in its pixels, from its top-left."""
    from matplotlib.ticker import MultipleLocator
    plt = _mpl()
    step = grid or grid_step(max(width, height))
    margin = 70                                     # px of the figure for axes and title
    small = image if image is not None else event_image(events, width, height)
    iw, ih = round(width * scale), round(height * scale)                 # the sensor's px
    fw, fh = round((width + margin) * scale), round((height + margin) * scale)   # figure px
    x0, y0 = round(margin * 0.6 * scale), round(margin * 0.3 * scale)   # the sensor's corner
    fig = plt.figure(figsize=(fw / 100, fh / 100), dpi=100)
    ax = fig.add_axes([x0 / fw, y0 / fh, iw / fw, ih / fh])
    raster = Path(out).suffix.lower() in RASTER
    if raster:                      # the picture goes under the axes (composited)
        fig.patch.set_alpha(0)
        ax.patch.set_visible(False)
    else:                           # a vector file: the picture inside it
        ax.imshow(small, interpolation="nearest")
    ax.set_xlim(-0.5, width - 0.5)
    ax.set_ylim(height - 0.5, -0.5)                 # y down, as the sensor and the model
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(MultipleLocator(step))
        axis.set_minor_locator(MultipleLocator(max(1, step // 5)))
    ax.tick_params(labelsize=6 * scale / 2, which="both", top=True, right=True,
                   labeltop=True, labelright=True)
    ax.grid(which="major", color="#444444", lw=0.5, alpha=0.6)
    ax.grid(which="minor", color="#888888", lw=0.3, alpha=0.35)
    ax.set_xlabel("x (px)", fontsize=7 * scale / 2)
    ax.set_ylabel("y (px)", fontsize=7 * scale / 2)
    import textwrap
    fig.text(0.01, 1 - 4 / (height + margin), textwrap.fill(title, int((width + margin) / 3.2)),
             fontsize=7 * scale / 2, family="monospace", va="top")
    if raster:
        _save_png(out, composited(fig, upscaled(small, scale), x0, y0))
    else:
        fig.savefig(out, dpi=100)
    x0, y0, x1, y1 = ax.get_window_extent().extents       # from the bottom-left
    h_px = fig.get_size_inches()[1] * fig.dpi
    plt.close(fig)
    return x0, h_px - y1, x1, h_px - y0
