"""``springtrack render``: the events alone with pixel axes (read positions off them), and
over a model checked against the recording's sensor."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from springtrack import io as stio
from springtrack.events import make
from springtrack.render import ON_RGB, grid_step, plot_events


def render_cli(*args):
    return subprocess.run([sys.executable, "-m", "springtrack.cli", "render", *map(str, args)],
                          capture_output=True, text=True, timeout=180)


def square(x0, y0, side, t0=0, p=1):
    xs, ys = np.meshgrid(np.arange(x0, x0 + side), np.arange(y0, y0 + side))
    n = xs.size
    return make(t0 + np.arange(n), xs.ravel(), ys.ravel(), p)


def test_a_position_read_off_the_picture_is_the_event_s(tmp_path):
    """A square of ON events at x 100..109, y 40..49 on a 320 x 240 sensor: mapped through
    the picture's axes, its red pixels lie at those sensor pixels."""
    import imageio.v2 as iio
    ev = square(100, 40, 10)
    out = tmp_path / "ev.png"
    left, top, right, bottom = plot_events(ev, 320, 240, out, title="t", scale=3.0)
    img = iio.imread(out)[..., :3] / 255.0
    red = np.all(np.abs(img - ON_RGB) < 0.02, axis=2)
    rows, cols = np.nonzero(red)
    sx = (cols - left) / (right - left) * 320          # picture px -> sensor px
    sy = (rows - top) / (bottom - top) * 240
    assert abs(sx.min() - 100) < 0.5 and abs(sx.max() - 110) < 0.5
    assert abs(sy.min() - 40) < 0.5 and abs(sy.max() - 50) < 0.5


def test_grid_spacing_is_round_and_readable():
    assert grid_step(304) == 20 and grid_step(640) == 50 and grid_step(1280) == 100
    assert grid_step(2048) == 200


@pytest.mark.slow
def test_render_without_a_model_draws_the_window_of_events(tmp_path):
    ev = np.concatenate([square(10, 10, 5, t0=0), square(200, 100, 5, t0=50_000)])
    src = tmp_path / "rec.raw"
    stio.write(src, ev, 320, 240)
    out = tmp_path / "grid.png"
    r = render_cli(src, "--out", out, "--start-us", 40_000)
    assert r.returncode == 0, r.stderr
    assert "25 events on the 320x240 sensor" in r.stderr and out.stat().st_size > 0
    for bad, msg in [(["--out", tmp_path / "v.gif"], "writes one picture"),
                     (["--out", out, "--track", "t.csv"], "--track needs --model")]:
        r = render_cli(src, *bad)
        assert r.returncode == 2 and msg in r.stderr, r.stderr


@pytest.mark.slow
def test_render_with_a_model_checks_it_against_the_recording(tmp_path):
    ev = square(150, 110, 8)
    src = tmp_path / "rec640.raw"
    stio.write(src, ev, 640, 480)
    r = render_cli(src, "--model", "grid3x3", "--out", tmp_path / "f.png")
    assert r.returncode == 2 and "304x240 but" in r.stderr and "640x480" in r.stderr
    r = render_cli(src, "--model", "grid3x3", "--out", tmp_path / "f.png", "--sensor-from",
                   "file")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "f.png").stat().st_size > 0


@pytest.mark.slow
@pytest.mark.parametrize("name", ["evt3_sample.raw", "dvs.es"])
def test_render_a_real_recording_without_a_model(data_file, tmp_path, name):
    out = tmp_path / "real.png"
    r = render_cli(data_file(name), "--out", out, "--dequantize")
    assert r.returncode == 0, r.stderr
    assert out.stat().st_size > 10_000


@pytest.mark.parametrize("width", [64, 128, 304, 346, 640])
def test_the_overlay_header_wraps_inside_the_picture(width):
    """Every line of the header, wrapped at the longest header text, is drawn inside the
    picture's width (Agg's hinted glyph advances are whole pixels: 9 pt monospace at
    100 dpi is 8 px a character, not 7.5)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from springtrack.render import Header
    head = Header(width * 2.0, 2.0)
    text = head.wrap(" ".join(["active"] * 40)[:Header.HEADER_CHARS])
    fig = plt.figure(figsize=(head.width_px / 100, 1), dpi=100)
    try:
        drawn = fig.text(0, 0.5, text, fontsize=head.fs, family="monospace")
        fig.canvas.draw()
        assert drawn.get_window_extent().width <= head.width_px, (width, text)
    finally:
        plt.close(fig)


def test_each_frame_ends_at_the_sample_it_draws():
    """Frames are drawn at sample times: with samples every 1 ms and a 0.5-ms window the
    frame's events end where its state was sampled (a frame between two samples drew the
    next one's state, a fast part's tracker one period ahead of its events); the middle
    frame alone for a picture; too many frames refused."""
    from springtrack.render import frame_rows
    t = np.arange(1_000, 51_000, 1_000)
    rows = frame_rows(t, 500, 20_000, False, 100)
    assert list(t[rows]) == [2_000, 22_000, 42_000]
    (mid,) = frame_rows(t, 500, 20_000, True, 100)
    assert t[mid] == 22_000
    with pytest.raises(ValueError, match="--max-frames"):
        frame_rows(t, 500, 100, False, 10)
