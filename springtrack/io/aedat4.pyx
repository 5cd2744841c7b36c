"""iniVation AEDAT 4.0 (DV): the file header, a streaming decoder of the events stream,
and an encoder (docs/formats.md#aedat-4).

A file is the magic ``#!AER-DAT4.0\\r\\n``, a uint32 LE length and an IOHeader FlatBuffer
(identifier ``IOHE``: compression, data table position, and the "info node", an XML
description of the streams), then packets: int32 LE stream id, uint32 LE size, and that many
bytes holding, compressed as the header says (LZ4 frame, Zstandard frame or none), a
size-prefixed FlatBuffer whose identifier names its content (``EVTS`` events, ``IMUS``,
``TRIG``, ``FRME``).  An event packet's table has one field, a vector of 16-byte Event
structs: int64 t (us), int16 x, int16 y, bool on, 3 bytes of padding -- the layout of
``EVENT_DTYPE``.  At the data table position (if any) an index of the packets ends the file.

The decoder returns the events of one events stream (the first one of the info node) and
counts the packets of the others by type; corrupt packets (bad compressed data, a FlatBuffer
whose offsets point outside it, an identifier other than the stream's, a decompressed size
over MAX_RATIO times the packet's) are counted and skipped, the packet framing carrying on
after them.  Timestamps are kept as recorded: absolute microseconds since the Unix epoch.
"""
from libc.stdint cimport uint8_t, uint16_t, uint32_t, int16_t, int64_t, uint64_t
from libc.string cimport memcpy
cimport numpy as cnp
import numpy as np
import xml.etree.ElementTree as ET

from springtrack.events cimport Event
from springtrack.io.base cimport *
from springtrack.io.base import encoder_input
from springtrack.events import EVENT_DTYPE
from springtrack.io.errors import DecodeError

cnp.import_array()

MAGIC = b"#!AER-DAT4.0\r\n"
HEADER_ID = b"IOHE"
# IOHeader.compression values (dv-processing's CompressionType)
COMPRESSION = {0: "NONE", 1: "LZ4", 2: "LZ4_HIGH", 3: "ZSTD", 4: "ZSTD_HIGH"}
# packet identifiers and the counter of the packets of that type we skip
STREAM_TYPES = {b"EVTS": "events", b"IMUS": "imu", b"TRIG": "triggers", b"FRME": "frames"}
MAX_HEADER = 1 << 24        # an IOHeader over 16 MiB is not a real file's
MAX_PACKET = 1 << 28        # nor a packet over 256 MiB: the framing is lost (see _decode)
MAX_RATIO = 32              # decompressed bytes per packet byte: cameras' events compress
                            # 2.1x (the DAVIS346 sample) to 4x (LZ4 of sorted zeros); LZ4 itself
                            # allows ~255x, which would let a 2.5 MB file decode to 2 GB
PACKET_EVENTS = 4096        # events per packet written by encode()

cdef enum:
    PACKET_HEAD = 8              # int32 stream id, uint32 size
    EVENT_BYTES = 16             # the Event struct: int64 t, int16 x, int16 y, bool on
    EV_T = 0                     # its fields' byte offsets
    EV_X = 8
    EV_Y = 10
    EV_ON = 12
    EVENTS_PACKET_FIELD = 0      # EventPacket: field 0, the vector of Event
    HEADER_COMPRESSION = 0       # IOHeader fields
    HEADER_DATA_TABLE = 1
    HEADER_INFO = 2
    # packet counters (info), by index
    PK_EVENTS = 0                # packets of the events stream decoded
    PK_OTHER_EVENTS = 1          # packets of another events stream
    PK_IMU = 2
    PK_TRIGGERS = 3
    PK_FRAMES = 4
    PK_OTHER = 5                 # a stream of a type we do not know
    PK_CORRUPT = 6               # anomaly: skipped
    N_PK = 7

PACKET_NAMES = ("event_packets", "other_event_packets", "imu_packets", "trigger_packets",
                "frame_packets", "other_packets", "corrupt_packets")


# ---- FlatBuffers, read with bounds checks (little-endian; flatbuffers.dev/internals) -----
class _Bad(Exception):
    """An offset or length outside the buffer."""


def _u(buf, Py_ssize_t pos, int size, bint signed=False):
    if pos < 0 or pos + size > len(buf):
        raise _Bad(f"{size}-byte field at {pos} outside {len(buf)} bytes")
    return int.from_bytes(buf[pos:pos + size], "little", signed=signed)


def _table(buf, Py_ssize_t root=0):
    """Position of the root table of the FlatBuffer starting at ``root``."""
    return root + _u(buf, root, 4)


def _field(buf, Py_ssize_t table, int index):
    """Position of field ``index`` of the table at ``table``, or -1 if absent."""
    cdef Py_ssize_t vt = table - _u(buf, table, 4, True)
    cdef int vt_size = _u(buf, vt, 2)
    if 4 + 2 * index + 2 > vt_size:
        return -1
    off = _u(buf, vt + 4 + 2 * index, 2)
    return table + off if off else -1


def _vector(buf, Py_ssize_t field, int item):
    """(position of the first item, item count) of the vector a field points to."""
    cdef Py_ssize_t start = field + _u(buf, field, 4)
    n = _u(buf, start, 4)
    if start + 4 + n * item > len(buf):
        raise _Bad(f"vector of {n} x {item} bytes at {start} outside {len(buf)} bytes")
    return start + 4, n


# ---- the file header ---------------------------------------------------------------------
def header_length(head: bytes) -> int:
    """Bytes of the magic, length and IOHeader (the first packet's offset), from the first
    18 bytes of a file."""
    return len(MAGIC) + 4 + int.from_bytes(head[len(MAGIC):len(MAGIC) + 4], "little")


def parse_header(head: bytes, path="<stream>") -> dict:
    """Parse the magic, IOHeader and info node.

    Returns ``offset`` (first packet), ``compression`` (name), ``data_table`` (file position
    of the packet index, -1 if none), ``streams`` ({id: {"type": identifier, "width",
    "height", "source", "ts_offset", "name"}}).  Raises DecodeError naming the problem."""
    if not head.startswith(MAGIC):
        raise DecodeError(f"{path}: not an AEDAT 4.0 file (no '#!AER-DAT4.0' magic)")
    if len(head) < len(MAGIC) + 4:
        raise DecodeError(f"{path}: AEDAT 4 header truncated before its length")
    offset = header_length(head)
    if offset - len(MAGIC) - 4 > MAX_HEADER:
        raise DecodeError(f"{path}: AEDAT 4 IOHeader length {offset - len(MAGIC) - 4} "
                          f"over {MAX_HEADER} bytes")
    if len(head) < offset:
        raise DecodeError(f"{path}: AEDAT 4 IOHeader truncated ({len(head) - len(MAGIC) - 4} "
                          f"of {offset - len(MAGIC) - 4} bytes)")
    buf = head[len(MAGIC) + 4:offset]
    try:
        table = _table(buf)
        f = _field(buf, table, HEADER_COMPRESSION)
        code = _u(buf, f, 4, True) if f >= 0 else 0
        f = _field(buf, table, HEADER_DATA_TABLE)
        data_table = _u(buf, f, 8, True) if f >= 0 else -1
        f = _field(buf, table, HEADER_INFO)
        if f < 0:
            raise _Bad("no info node")
        start, n = _vector(buf, f, 1)
        text = bytes(buf[start:start + n]).decode("utf-8")
    except (_Bad, UnicodeDecodeError) as e:
        raise DecodeError(f"{path}: AEDAT 4 IOHeader unreadable: {e}") from None
    if code not in COMPRESSION:
        raise DecodeError(f"{path}: AEDAT 4 compression {code} unknown "
                          f"(known: {', '.join(COMPRESSION.values())})")
    if data_table != -1 and data_table < offset:
        raise DecodeError(f"{path}: AEDAT 4 data table position {data_table} inside the header")
    return {"offset": offset, "compression": COMPRESSION[code], "data_table": data_table,
            "streams": _streams(text, path)}


def _streams(text: str, path) -> dict:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise DecodeError(f"{path}: AEDAT 4 info node is not XML: {e}") from None
    out = root.find("./node[@name='outInfo']")
    if out is None:
        raise DecodeError(f"{path}: AEDAT 4 info node has no 'outInfo' node (no streams)")
    streams = {}
    for node in out.findall("./node"):
        try:
            sid = int(node.get("name", ""))
        except ValueError:
            raise DecodeError(f"{path}: AEDAT 4 stream name {node.get('name')!r} is not an "
                              "integer id") from None
        attrs = {a.get("key"): (a.text or "").strip() for a in node.findall("./attr")}
        info = {a.get("key"): (a.text or "").strip() for a in node.findall("./node[@name='info']/attr")}
        s = {"type": attrs.get("typeIdentifier", ""), "name": attrs.get("originalOutputName", ""),
             "source": info.get("source", ""), "ts_offset": info.get("tsOffset", "")}
        if s["type"] in ("EVTS", "FRME"):
            for key, dim in (("sizeX", "width"), ("sizeY", "height")):
                try:
                    s[dim] = int(info[key])
                except (KeyError, ValueError):
                    raise DecodeError(f"{path}: AEDAT 4 stream {sid} ({s['type']}) has no "
                                      f"integer {key} in its info node") from None
                if not 0 < s[dim] <= 65535:
                    raise DecodeError(f"{path}: AEDAT 4 stream {sid} {key} {s[dim]} out of "
                                      "range 1..65535")
        streams[sid] = s
    if not streams:
        raise DecodeError(f"{path}: AEDAT 4 info node lists no streams")
    return streams


def describe_streams(streams: dict) -> str:
    """One line for ``springtrack info``: '0 events (EVTS 320x240, DVXplorer), 2 imu (IMUS)'."""
    parts = []
    for sid, s in sorted(streams.items()):
        geom = f" {s['width']}x{s['height']}" if "width" in s else ""
        src = f", {s['source']}" if s.get("source") else ""
        parts.append(f"{sid} {s.get('name') or '?'} ({s['type']}{geom}{src})")
    return ", ".join(parts)


# ---- the decoder --------------------------------------------------------------------------
def _decompressor(str compression):
    """A function bytes -> bytes (at most ``limit`` + 1 bytes out) for ``compression``."""
    if compression == "NONE":
        return lambda data, limit: bytes(data[:limit + 1])
    if compression.startswith("LZ4"):
        import lz4.frame
        def lz4_frame(data, limit):
            d = lz4.frame.LZ4FrameDecompressor()
            out = d.decompress(data, max_length=limit + 1)
            if not d.eof and len(out) <= limit:
                raise _Bad("LZ4 frame truncated")
            return out
        return lz4_frame
    import zstandard
    dctx = zstandard.ZstdDecompressor()
    def zstd_frame(data, limit):
        with dctx.stream_reader(data, read_across_frames=False) as r:
            return r.read(limit + 1)
    return zstd_frame


cdef class Aedat4Decoder(Decoder):
    """Packets (after the file header) to the events of one events stream.

    ``streams``: {id: type identifier} from the info node (packets of an id not in it are
    'unknown_type'); ``event_stream``: the id whose events are returned (default: the lowest
    EVTS id); ``compression``: the header's; ``data_end``: bytes of packets before the data
    table (-1: to the end; bytes after it are counted in 'data_table_bytes' and ignored)."""
    cdef object streams, decompress, pending
    cdef readonly int event_stream
    cdef readonly str compression
    cdef int64_t data_end, consumed, last_t, table_bytes, lost_bytes
    cdef bint lost                  # a packet size over MAX_PACKET: framing lost
    cdef uint64_t packets[<int>N_PK]

    def __init__(self, int width=0, int height=0, streams=None, event_stream=None,
                 str compression="LZ4", data_end=-1):
        self._setup("aedat4", 1, MAX_RATIO // EVENT_BYTES, 4, width, height, False)
        self.streams = {0: "EVTS"} if streams is None else dict(streams)
        evts = sorted(i for i, t in self.streams.items() if t == "EVTS")
        if event_stream is None:
            if not evts:
                raise ValueError("aedat4 decoder: no events (EVTS) stream among "
                                 f"{self.streams}")
            event_stream = evts[0]
        self.event_stream = event_stream
        if compression not in COMPRESSION.values():
            raise ValueError(f"aedat4 decoder: compression {compression!r} unknown "
                             f"(known: {', '.join(COMPRESSION.values())})")
        self.compression = compression
        self.decompress = _decompressor(compression)
        self.pending = bytearray()
        self.data_end = -1 if data_end is None else data_end
        self.last_t = -(1 << 62)

    cdef int _pending_state(self) noexcept:
        return len(self.pending)

    cdef void _reset_state(self) noexcept:
        self.pending = bytearray()

    @property
    def stats(self):
        s = Decoder.stats.__get__(self)
        s.anomalies["corrupt_packets"] = int(self.packets[<int>PK_CORRUPT])
        for i in range(<int>PK_CORRUPT):
            if self.packets[i]:
                s.info[PACKET_NAMES[i]] = int(self.packets[i])
        s.anomalies["unframed_bytes"] = int(self.lost_bytes)
        if self.table_bytes:
            s.info["data_table_bytes"] = int(self.table_bytes)
        return s

    def decode_into(self, buffer, out, Py_ssize_t start=0):
        """As Decoder.decode_into; ``out`` needs room for MAX_RATIO // 16 events per byte of
        ``buffer`` and of the pending packet (the most a packet may decompress to)."""
        need = (len(memoryview(buffer).cast("B")) + len(self.pending)) * self.max_per_word
        if isinstance(out, np.ndarray) and out.ndim == 1 and out.shape[0] - start < need:
            raise ValueError(f"decode_into: out has room for {out.shape[0] - start} events "
                             f"from index {start}; this buffer may produce {need}")
        return Decoder.decode_into(self, buffer, out, start)

    cdef object _decode(self, buffer, object out, Py_ssize_t* nout_p):
        cdef Py_ssize_t start = nout_p[0]
        out = self._packets(buffer, out, nout_p)
        self.events_out += nout_p[0] - start
        return out

    cdef object _packets(self, buffer, object out, Py_ssize_t* nout_p):
        """Decode the whole packets completed by ``buffer`` (the rest waits in pending)."""
        data = memoryview(buffer).cast("B")
        cdef Py_ssize_t n = len(data), pos = 0, k, size
        if self.data_end >= 0 and self.consumed + n > self.data_end:
            k = max(0, self.data_end - self.consumed)
            self.table_bytes += n - k
            data = data[:k]
            n = k
        self.consumed += n
        if self.lost:
            self.lost_bytes += n
            return out
        if self.pending:                  # complete the packet split by the previous calls
            k = min(PACKET_HEAD - len(self.pending), n) if len(self.pending) < PACKET_HEAD else 0
            self.pending += data[:k]
            pos = k
            if len(self.pending) < PACKET_HEAD:
                return out
            size = int.from_bytes(self.pending[4:8], "little")
            if size > MAX_PACKET:
                self._lose(n - pos)
                return out
            k = min(PACKET_HEAD + size - len(self.pending), n - pos)
            self.pending += data[pos:pos + k]
            pos += k
            if len(self.pending) < PACKET_HEAD + size:
                return out
            packet, self.pending = self.pending, bytearray()
            out = self._packet(int.from_bytes(packet[:4], "little", signed=True),
                               memoryview(packet)[PACKET_HEAD:], out, nout_p)
        while n - pos >= PACKET_HEAD:
            size = int.from_bytes(data[pos + 4:pos + 8], "little")
            if size > MAX_PACKET:
                self._lose(n - pos)
                return out
            if n - pos - PACKET_HEAD < size:
                break
            out = self._packet(int.from_bytes(data[pos:pos + 4], "little", signed=True),
                               data[pos + PACKET_HEAD:pos + PACKET_HEAD + size], out, nout_p)
            pos += PACKET_HEAD + size
        if pos < n:                       # a packet split by the end of this buffer
            self.pending += data[pos:]
        return out

    cdef void _lose(self, Py_ssize_t rest):
        """A packet size over MAX_PACKET: no AEDAT 4 file has one, and the format has no
        sync marker to find the next packet, so the rest of the stream is counted
        ('unframed_bytes', with the pending packet) and dropped."""
        self.lost = True
        self.packets[<int>PK_CORRUPT] += 1
        self.lost_bytes += rest + len(self.pending)
        self.pending = bytearray()

    cdef object _packet(self, int sid, payload, object out, Py_ssize_t* nout_p):
        """Decode one packet's payload: events appended to out (grown if needed)."""
        self.n.words += 1
        kind = self.streams.get(sid)
        if kind is None:
            self.n.anomalies[<int>AN_UNKNOWN_TYPE] += 1
            return out
        if sid != self.event_stream:
            self.packets[{"EVTS": PK_OTHER_EVENTS, "IMUS": PK_IMU, "TRIG": PK_TRIGGERS,
                          "FRME": PK_FRAMES}.get(kind, PK_OTHER)] += 1
            return out
        try:
            buf = self.decompress(payload, len(payload) * MAX_RATIO)
            if len(buf) > len(payload) * MAX_RATIO:
                raise _Bad(f"decompresses to over {MAX_RATIO} times its size")
            if _u(buf, 0, 4) > len(buf) - 4 or buf[8:12] != b"EVTS":
                raise _Bad("not a size-prefixed EVTS FlatBuffer")
            f = _field(buf, _table(buf, 4), EVENTS_PACKET_FIELD)
            first, count = _vector(buf, f, EVENT_BYTES) if f >= 0 else (0, 0)
        except Exception:       # noqa: BLE001 - any failure of a packet is the same anomaly
            self.packets[<int>PK_CORRUPT] += 1
            return out
        self.packets[<int>PK_EVENTS] += 1
        cdef Py_ssize_t nout = nout_p[0]
        if out.shape[0] - nout < count:
            bigger = np.empty(max(2 * out.shape[0], nout + count), EVENT_DTYPE)
            bigger[:nout] = out[:nout]
            out = bigger
        if count:
            nout_p[0] = nout + self._events(buf, first, count, out, nout)
        return out

    cdef Py_ssize_t _events(self, buf, Py_ssize_t first, Py_ssize_t count, object out,
                            Py_ssize_t nout):
        """Copy ``count`` Event structs at ``buf[first:]`` into ``out[nout:]``, checking
        geometry and counting time steps back; return the number kept."""
        cdef const uint8_t[::1] src = memoryview(buf).cast("B")
        cdef const uint8_t* p = &src[first]
        cdef Event* o = <Event*>cnp.PyArray_DATA(<cnp.ndarray>out) + nout
        cdef uint32_t W = geometry_bound(self.width)
        cdef uint32_t H = geometry_bound(self.height)
        cdef int64_t t, last_t = self.last_t
        cdef int16_t x, y
        cdef Py_ssize_t i, k = 0
        cdef uint64_t geo = 0, back = 0
        with nogil:
            for i in range(count):
                memcpy(&t, p + EVENT_BYTES * i + EV_T, 8)
                memcpy(&x, p + EVENT_BYTES * i + EV_X, 2)
                memcpy(&y, p + EVENT_BYTES * i + EV_Y, 2)
                if t < last_t:
                    back += 1
                last_t = t
                if x < 0 or y < 0 or <uint32_t>x >= W or <uint32_t>y >= H:
                    geo += 1
                    continue
                put_event(&o[k], t, <uint16_t>x, <uint16_t>y, p[EVENT_BYTES * i + EV_ON] != 0)
                k += 1
        self.last_t = last_t
        self.n.anomalies[<int>AN_OUT_OF_GEOMETRY] += geo
        self.n.anomalies[<int>AN_TIME_BACKWARDS] += back
        return k


# ---- the encoder --------------------------------------------------------------------------
def _flatbuffer_header(str compression, str info) -> bytes:
    """The IOHeader FlatBuffer: root offset, 'IOHE', vtable, table (soffset, compression,
    data table position -1, info node offset), string."""
    text = info.encode()
    vtable = np.array([10, 24, 4, 8, 16], "<u2").tobytes()        # at 8, padded to 24
    table = (np.array([24 - 8, [k for k, v in COMPRESSION.items() if v == compression][0]],
                      "<i4").tobytes() + np.array([-1], "<i8").tobytes()
             + np.array([48 - 40, 0], "<u4").tobytes())           # at 24: string at 48
    string = np.array([len(text)], "<u4").tobytes() + text + b"\0"
    buf = (np.array([24], "<u4").tobytes() + HEADER_ID + vtable + b"\0" * 6 + table + string)
    return buf + b"\0" * (-len(buf) % 8)


def _event_packet(ev) -> bytes:
    """A size-prefixed EVTS FlatBuffer: size, root offset, 'EVTS', vtable, table (soffset,
    vector offset), vector length, events at byte 32 (8-aligned)."""
    head = np.array([28 + EVENT_BYTES * len(ev), 16], "<u4").tobytes() + b"EVTS"
    head += np.array([6, 8, 4, 0], "<u2").tobytes()                # vtable at 12 (pad 2)
    head += np.array([8, 4, len(ev)], "<u4").tobytes()             # table at 20, vector at 28
    body = np.zeros(len(ev), EVENT_DTYPE)
    for f in ("t", "x", "y", "p"):
        body[f] = ev[f]
    return head + body.tobytes()


def info_node(int width, int height, str compression="LZ4", str source="springtrack") -> str:
    return (
        '<dv version="2.0">\n'
        '    <node name="outInfo" path="/mainloop/Recorder/outInfo/">\n'
        '        <node name="0" path="/mainloop/Recorder/outInfo/0/">\n'
        f'            <attr key="compression" type="string">{compression}</attr>\n'
        '            <attr key="originalModuleName" type="string">springtrack</attr>\n'
        '            <attr key="originalOutputName" type="string">events</attr>\n'
        '            <attr key="typeDescription" type="string">Array of events (polarity '
        'ON/OFF).</attr>\n'
        '            <attr key="typeIdentifier" type="string">EVTS</attr>\n'
        '            <node name="info" path="/mainloop/Recorder/outInfo/0/info/">\n'
        f'                <attr key="sizeX" type="int">{width}</attr>\n'
        f'                <attr key="sizeY" type="int">{height}</attr>\n'
        f'                <attr key="source" type="string">{source}</attr>\n'
        '                <attr key="tsOffset" type="long">0</attr>\n'
        '            </node>\n'
        '        </node>\n'
        '    </node>\n'
        '</dv>\n')


def compress(str compression, data: bytes) -> bytes:
    if compression == "NONE":
        return data
    if compression.startswith("LZ4"):
        import lz4.frame
        return lz4.frame.compress(data, compression_level=9 if compression == "LZ4_HIGH" else 0)
    import zstandard
    return zstandard.ZstdCompressor(level=19 if compression == "ZSTD_HIGH" else 3).compress(data)


def encode(events, int width, int height, str compression="LZ4",
           int packet_events=PACKET_EVENTS) -> bytes:
    """A complete AEDAT 4.0 file with one events stream (id 0), ``packet_events`` events per
    packet, compressed with ``compression`` (NONE, LZ4, LZ4_HIGH, ZSTD, ZSTD_HIGH), no data
    table.  Timestamps must be >= 0 and non-decreasing."""
    if compression not in COMPRESSION.values():
        raise ValueError(f"aedat4 encode: compression {compression!r} unknown "
                         f"(known: {', '.join(COMPRESSION.values())})")
    if packet_events < 1:
        raise ValueError(f"aedat4 encode: packet_events must be >= 1, got {packet_events}")
    ev = encoder_input(events, "aedat4", min(width, 32768), min(height, 32768))
    header = _flatbuffer_header(compression, info_node(width, height, compression))
    parts = [MAGIC, np.array([len(header)], "<u4").tobytes(), header]
    for i in range(0, len(ev), packet_events):
        payload = compress(compression, _event_packet(ev[i:i + packet_events]))
        parts.append(np.array([0, len(payload)], "<u4").tobytes() + payload)
    return b"".join(parts)
