"""``dv://HOST:PORT`` and ``dv:camera[:SERIAL]``: iniVation's DV software and cameras
through ``dv-processing`` (the optional extra ``springtrack[dv]``).

* ``dv://HOST:PORT`` connects to a DV network event stream: the TCP server of a DV
  "Output > Network TCP server" module, or any ``dv.io.NetworkWriter``.  The sensor's
  geometry is the stream's own (its event resolution); times are the stream's (µs since
  the Unix epoch, as DV stamps them), so a stream tracks exactly as the AEDAT 4 file DV
  would record from it.  Options: ``?reconnect=S`` (after a drop, try to connect again for
  S seconds; each reconnection counted), ``?gap=S`` (a silence longer than S s counts as a
  gap, default 0.5).
* ``dv:camera`` opens the first attached iniVation camera (DVXplorer, DAVIS, DVS128) with
  ``dv.io.camera.open()``, ``dv:camera:SERIAL`` the one with that serial number.

Each poll takes the batches ready now (``getNextEventBatch``; nothing ready: the reader
waits ``base.POLL_S``); the stream ends when the reader stops running (the server closed
or the connection dropped; the camera unplugged).
"""
from __future__ import annotations

import time

import numpy as np

from ..extras import need
from .base import GAP_S, Batch, LiveReader, options, positive_seconds

USAGE = "dv://HOST:PORT | dv:camera[:SERIAL]"
HELP = ("a DV network event stream (DV's TCP output, dv.io.NetworkWriter), or an attached "
        "iniVation camera (first found, or by serial); geometry from the stream; needs "
        "pip install 'springtrack[dv]'")
OPTIONS = {"reconnect": (positive_seconds, 0.0), "gap": (positive_seconds, GAP_S)}
RETRY_S = 0.2            # wait between connection attempts while reconnecting (s)
# dv-processing's event record, renamed to the fields as_events reads
_DV_NAMES = {"timestamp": "t", "x": "x", "y": "y", "polarity": "p"}


def dv_module():
    """``dv_processing``, or MissingExtra naming the extra that installs it."""
    return need("dv_processing", "dv", "dv:// and dv:camera sources")


def as_fields(arr: np.ndarray) -> np.ndarray:
    """dv-processing's event array (timestamp, x, y, polarity) viewed with the fields
    t, x, y, p (no copy)."""
    dt = arr.dtype
    return arr.view(np.dtype({"names": [_DV_NAMES[n] for n in dt.names],
                              "formats": [dt.fields[n][0] for n in dt.names],
                              "offsets": [dt.fields[n][1] for n in dt.names],
                              "itemsize": dt.itemsize}))


def parse_address(target: str, url: str) -> tuple[str, int, str]:
    """(host, port, query) of ``//HOST:PORT[?options]``."""
    hostport, _, query = target[2:].partition("?")
    host, sep, port = hostport.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"{url}: give the stream's address as dv://HOST:PORT "
                         f"(e.g. dv://127.0.0.1:7777)")
    return host.strip("[]"), int(port), query


def connect(dv, host: str, port: int, url: str):
    """A ``dv.io.NetworkReader`` on ``host:port``; ConnectionError naming the address."""
    try:
        return dv.io.NetworkReader(host, port)
    except RuntimeError as e:
        why = str(e).splitlines()[0].split(" [")[0]
        raise ConnectionError(f"{url}: cannot connect to a DV stream at {host}:{port}: {why} "
                              f"(is DV's network output, or the sender, running there?)") from None


def open_camera(dv, serial: str, url: str):
    """The attached camera ``serial`` names (empty: the first); ConnectionError listing
    what is attached when it is not there."""
    found = dv.io.camera.discover()
    serials = [d.serialNumber for d in found]
    if not found:
        raise ConnectionError(f"{url}: no iniVation camera is attached (dv-processing finds "
                              f"none): plug one in, check its USB permissions "
                              f"(docs/live.md, Cameras), or read a stream with dv://HOST:PORT")
    if serial and serial not in serials:
        raise ConnectionError(f"{url}: no attached camera has serial {serial!r}; attached: "
                              f"{', '.join(serials)}")
    try:
        return dv.io.camera.open(serial) if serial else dv.io.camera.open()
    except (RuntimeError, IndexError) as e:
        raise ConnectionError(f"{url}: the camera did not open: {str(e).splitlines()[0]}") from None


def _reader(source, url: str, fmt: str, gap_s: float, reconnect=None) -> LiveReader:
    """A LiveReader polling ``source`` (a NetworkReader or camera); ``reconnect()``
    returns a new one after a drop (or None: the stream is over)."""
    if not source.isEventStreamAvailable():
        raise ValueError(f"{url}: the stream carries no events (frames or IMU only?)")
    w, h = source.getEventResolution()
    state = {"src": source}
    reader: LiveReader

    def poll() -> Batch:
        batch = state["src"].getNextEventBatch()
        if batch is not None:
            return Batch(as_fields(batch.numpy()))
        if state["src"].isRunning():
            return Batch()
        new = reconnect() if reconnect is not None else None
        if new is None:
            return Batch(ended="the sender closed the stream or the connection dropped"
                         if fmt == "dv" else "the camera stopped (unplugged?)")
        if tuple(new.getEventResolution()) != (w, h):
            return Batch(ended=f"reconnected to a {new.getEventResolution()} stream, "
                               f"not {w}x{h}")
        state["src"] = new
        reader.stats.reconnects += 1
        return Batch()

    reader = LiveReader(url, fmt, int(w), int(h), poll, gap_s=gap_s,
                        header={"camera": source.getCameraName(),
                                "geometry_source": "the stream's event resolution"})
    return reader


def open(target: str, url: str) -> LiveReader:             # noqa: A001
    if target.startswith("//"):
        host, port, query = parse_address(target, url)
        opts = options(url, query, OPTIONS)
        dv = dv_module()

        def reconnect():
            end = time.monotonic() + opts["reconnect"]
            while time.monotonic() < end:
                try:
                    return connect(dv, host, port, url)
                except ConnectionError:
                    time.sleep(RETRY_S)
            return None
        return _reader(connect(dv, host, port, url), url, "dv", opts["gap"],
                       reconnect if opts["reconnect"] > 0 else None)
    kind, _, serial = target.partition(":")
    if kind != "camera":
        raise ValueError(f"{url}: a DV source is {USAGE}")
    dv = dv_module()
    return _reader(open_camera(dv, serial, url), url, "dv-camera", GAP_S)
