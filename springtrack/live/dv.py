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

A thread (:class:`Drain`) takes the packets as they come (``getNextEventBatch``) into a
bounded queue; each poll joins those waiting.  The stream ends when the reader stops
running (the server closed or the connection dropped; the camera unplugged) and the
packets before that are consumed.
"""
from __future__ import annotations

import queue
import threading
import time

import numpy as np

from .extras import need
from .base import GAP_S, MAX_COALESCE, POLL_S, Batch, LiveReader, joined, options, positive_seconds

USAGE = "dv://HOST:PORT | dv:camera[:SERIAL]"
HELP = ("a DV network event stream (DV's TCP output, dv.io.NetworkWriter), or an attached "
        "iniVation camera (first found, or by serial); geometry from the stream; needs "
        "pip install 'springtrack[dv]'")
OPTIONS = {"reconnect": (positive_seconds, 0.0), "gap": (positive_seconds, GAP_S)}
RETRY_S = 0.2            # wait between connection attempts while reconnecting (s)
QUEUE_PACKETS = 4096     # packets a reader holds for a consumer that falls behind
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


class Drain:
    """A thread taking the source's packets as they come into a bounded queue.

    dv-processing's readers read the socket only when asked, and a stream closed while
    packets wait unread is reset and loses them: the thread keeps asking, so a consumer
    that starts late or falls behind loses nothing.  The queue holds QUEUE_PACKETS; when
    it is full the thread waits and TCP's flow control holds the sender back (memory
    stays bounded).  An item is an event array, or the string saying why the stream ended.
    """

    def __init__(self, source, url: str, fmt: str, reconnect=None):
        self.source = source
        self.url = url
        self.fmt = fmt
        self.reconnect = reconnect
        self.reconnects = 0
        self.ended: str | None = None     # why the stream ended, once the thread said so
        self.resolution = tuple(source.getEventResolution())
        self.queue: queue.Queue = queue.Queue(QUEUE_PACKETS)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name=f"springtrack {url}", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            while not self.stop.is_set():
                batch = self.source.getNextEventBatch()
                if batch is not None:
                    self._put(np.array(batch.numpy()))
                elif self.source.isRunning():
                    time.sleep(POLL_S)
                else:
                    why = self._reconnected()
                    if why is not None:
                        self._put(why)
                        return
        except Exception as e:            # the reader's own error ends the stream, said
            self._put(f"the reader failed: {str(e).splitlines()[0]}")

    def _reconnected(self) -> str | None:
        """None once connected again, else why the stream is over."""
        new = self.reconnect() if self.reconnect is not None else None
        if new is None:
            return ("the sender closed the stream or the connection dropped"
                    if self.fmt == "dv" else "the camera stopped (unplugged?)")
        if tuple(new.getEventResolution()) != self.resolution:
            return (f"reconnected to a {new.getEventResolution()} stream, not "
                    f"{self.resolution}")
        self.source = new
        self.reconnects += 1
        return None

    def _put(self, item) -> None:
        while not self.stop.is_set():
            try:
                self.queue.put(item, timeout=0.1)
                return
            except queue.Full:
                continue

    def poll(self) -> Batch:
        parts = []
        while len(parts) < MAX_COALESCE:
            try:
                item = self.queue.get_nowait()
            except queue.Empty:
                break
            if isinstance(item, str):             # the last item: the thread has ended
                self.ended = item
                break
            parts.append(item)
        if parts:
            return Batch(as_fields(joined(parts)), packets=len(parts))
        return Batch(ended=self.ended)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=1.0)


def _reader(source, url: str, fmt: str, gap_s: float, reconnect=None) -> LiveReader:
    """A LiveReader over ``source`` (a NetworkReader or camera) drained by a thread;
    ``reconnect()`` returns a new source after a drop (or None: the stream is over)."""
    if not source.isEventStreamAvailable():
        raise ValueError(f"{url}: the stream carries no events (frames or IMU only?)")
    w, h = source.getEventResolution()
    drain = Drain(source, url, fmt, reconnect)
    reader: LiveReader

    def poll() -> Batch:
        b = drain.poll()
        reader.stats.reconnects = drain.reconnects
        return b

    reader = LiveReader(url, fmt, int(w), int(h), poll, gap_s=gap_s, close=drain.close,
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
