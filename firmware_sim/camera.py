"""Camera access through pyusb: find, configure and read an event camera's bulk stream.

The CCam ATIS sequence follows the public ``neuromorphic-paris/ccam_atis_sepia`` driver
(docs/hardware.md):

1. find VID 0x04B4 / PID 0x00F4 (optionally a serial), claim interface 0;
2. serial: vendor IN request (bmRequestType 0xC0, bRequest 0x55, wValue 0x20, 8 bytes),
   serial = bytes 6-7 (big-endian);
3. role: 4-byte commands to registers 0x01A <- 1 and 0x41A <- 2 (as the driver does);
4. biases: vendor OUT requests 0x61 then 0x62 with (value, tension, address) triples, each
   a big-endian uint32 (:func:`bias_payload`);
5. commands (0x40, bRequest 0x56, wValue = register, 4 bytes big-endian): flush biases
   (0x00A, 0x40A <- 0x40), set mode (0x008, 0x408 <- 0x32C), drain one bulk read, start
   (0x000, 0x400 <- 0xC81);
6. bulk IN endpoint 0x81 in 128 KiB transfers, each with a finite timeout.

:class:`Camera` works on any ``usb.core.Device``: the libusb backend on real hardware or
``firmware_sim.simcam.SimBackend`` (same code path).  A :class:`DeviceProfile` selects
IDs, geometry and the word format the fused loop decodes; the Prophesee EVT 2.0 / 2.1 /
3.0 profiles only read the bulk stream (no register control of those boards: out of scope,
docs/firmware.md).
"""
from __future__ import annotations

import array
import errno
import struct
from dataclasses import dataclass

import usb.core
import usb.util

CCAM_VID = 0x04B4
CCAM_PID = 0x00F4
EP_IN = 0x81
INTERFACE = 0
TRANSFER_BYTES = 128 * 1024          # multiple of wMaxPacketSize (512 at high speed)
READ_TIMEOUT_MS = 20                 # finite everywhere: a blocking read can hang on unplug
CTRL_TIMEOUT_MS = 500

# vendor requests (bmRequestType, bRequest)
REQ_SERIAL = (0xC0, 0x55)
SERIAL_WVALUE = 0x20
REQ_BIAS_A = (0x40, 0x61)
REQ_BIAS_B = (0x40, 0x62)
REQ_COMMAND = (0x40, 0x56)

# register commands (wValue, value): each goes to the two halves 0x0xx / 0x4xx
CMD_ROLE = ((0x01A, 0x00000001), (0x41A, 0x00000002))
CMD_FLUSH_BIASES = ((0x00A, 0x00000040), (0x40A, 0x00000040))
CMD_SET_MODE = ((0x008, 0x0000032C), (0x408, 0x0000032C))
CMD_START = ((0x000, 0x00000C81), (0x400, 0x00000C81))
CMD_STOP = ((0x000, 0x00000000), (0x400, 0x00000000))

# Bias set of the CCam ATIS: name -> (default value, tension, address), the driver's
# defaults.  Values are 0..255 DAC codes; tension and address are fixed by the board.
BIASES: dict[str, tuple[int, int, int]] = {
    # change detection
    "reset_switch_bulk_potential": (207, 0x5900, 0x02),
    "photoreceptor_feedback": (243, 0x5900, 0x03),
    "refractory_period": (216, 0x5900, 0x04),
    "follower": (239, 0x5900, 0x05),
    "event_source_amplifier": (42, 0x7900, 0x06),
    "on_event_threshold": (51, 0x7900, 0x07),
    "off_event_threshold": (39, 0x7900, 0x08),
    "off_event_inverter": (61, 0x7900, 0x09),
    "cascode_photoreceptor_feedback": (154, 0x7900, 0x0A),
    # exposure measurement
    "comparator_tail": (54, 0x7900, 0x0B),
    "comparator_hysteresis": (47, 0x7900, 0x0C),
    "comparator_output_stage": (57, 0x7900, 0x0D),
    "upper_threshold": (243, 0x5900, 0x0E),
    "lower_threshold": (235, 0x5900, 0x0F),
    # pull-ups
    "exposure_measurement_abscissa_request": (131, 0x5900, 0x10),
    "exposure_measurement_ordinate_request": (155, 0x5900, 0x11),
    "change_detection_abscissa_request": (151, 0x5900, 0x12),
    "change_detection_ordinate_request": (117, 0x7900, 0x13),
    "abscissa_acknoledge": (162, 0x5900, 0x14),
    "abscissa_encoder": (162, 0x5900, 0x15),
    "ordinate_encoder": (120, 0x7900, 0x16),
    # control
    "exposure_measurement_timeout": (49, 0x7900, 0x17),
    "sequential_exposure_measurement_timeout": (45, 0x7900, 0x18),
    "abscissa_acknoledge_timeout": (56, 0x7900, 0x19),
    "latch_cell_scan_pulldown": (134, 0x5900, 0x1A),
    "abscissa_request_pulldown": (87, 0x7900, 0x1B),
}
# static entries sent with every bias load (value fixed by the driver)
STATIC_BIASES = {"reset_t": (0, 0x5900, 0x00), "test_event": (0, 0x7900, 0x01),
                 "reset_photodiodes": (3, 0x00, 0x1C)}


class CameraError(RuntimeError):
    """Device not found, refused a request, or vanished; the message says which."""


def default_biases() -> dict[str, int]:
    return {k: v[0] for k, v in BIASES.items()}


def check_biases(values: dict) -> dict[str, int]:
    """Validate bias overrides (known name, integer 0..255); returns the full set."""
    out = default_biases()
    for k, v in values.items():
        if k not in BIASES:
            raise ValueError(f"unknown bias {k!r}; known: {', '.join(BIASES)}")
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 255:
            raise ValueError(f"bias {k} must be an integer 0..255, got {v!r}")
        out[k] = v
    return out


def bias_payload(values: dict | None = None) -> bytes:
    """(value, tension, address) big-endian uint32 triples, biases then static entries."""
    vals = check_biases(values or {})
    parts = [struct.pack(">III", vals[k], t, a) for k, (_, t, a) in BIASES.items()]
    parts += [struct.pack(">III", v, t, a) for v, t, a in STATIC_BIASES.values()]
    return b"".join(parts)


def parse_bias_payload(data: bytes) -> dict[int, tuple[int, int]]:
    """address -> (value, tension) of a bias payload; ValueError if malformed."""
    if len(data) == 0 or len(data) % 12:
        raise ValueError(f"bias payload of {len(data)} bytes is not a non-empty multiple of 12")
    return {a: (v, t) for v, t, a in struct.iter_unpack(">III", bytes(data))}


@dataclass(frozen=True)
class DeviceProfile:
    """How to find and read one kind of camera.

    ``fmt``: the bulk word format, decoded by the fused loop (``firmware_sim._fused``:
    ``ccam``, ``evt2``, ``evt21``, ``evt3``); ``width`` x ``height``: the sensor (a default
    for the EVT boards, whose sensors vary: ``dataclasses.replace`` it, as ``replay:``
    does with a file's geometry); ``legacy``: EVT 2.1 words in the IMX636 order;
    ``configure``: whether the CCam register sequence is sent (newer Prophesee boards: no,
    see docs/firmware.md).
    """
    name: str
    vid: int
    pid: int
    fmt: str
    width: int
    height: int
    configure: bool
    ep_in: int = EP_IN
    legacy: bool = False
    notes: str = ""


PROFILES: dict[str, DeviceProfile] = {p.name: p for p in (
    DeviceProfile("ccam_atis", CCAM_VID, CCAM_PID, "ccam", 304, 240, True,
                  notes="CCam ATIS (ccam_atis_sepia protocol)"),
    DeviceProfile("evt2", CCAM_VID, 0x00F5, "evt2", 640, 480, False,
                  notes="Prophesee Gen3 board streaming EVT 2.0; stream must be started by "
                        "the vendor tools (no register control here); set --vid/--pid"),
    DeviceProfile("evt21", CCAM_VID, 0x00F5, "evt21", 320, 320, False,
                  notes="Prophesee GENX320 board streaming EVT 2.1 (64-bit word order); as evt2"),
    DeviceProfile("evt3", CCAM_VID, 0x00F5, "evt3", 1280, 720, False,
                  notes="Prophesee Gen4 board streaming EVT 3.0; as evt2"),
)}


def make_decoder(profile: DeviceProfile):
    """A ``springtrack.io`` streaming decoder of the profile's words at its geometry, for
    the non-fused path: a kernel with no C-level step for the fused loop (the
    microcontroller build in its emulator)."""
    from springtrack.io import decoder
    if profile.fmt == "ccam":
        return decoder("ccam")
    if profile.fmt not in ("evt2", "evt21", "evt3"):
        raise CameraError(f"profile {profile.name}: format {profile.fmt!r} has no streaming decoder")
    opts = {"legacy": profile.legacy} if profile.fmt == "evt21" else {}
    return decoder(profile.fmt, width=profile.width, height=profile.height, **opts)


def read_serial(dev) -> int:
    data = dev.ctrl_transfer(REQ_SERIAL[0], REQ_SERIAL[1], SERIAL_WVALUE, 0, 8, CTRL_TIMEOUT_MS)
    if len(data) < 8:
        raise CameraError(f"serial request returned {len(data)} bytes, expected 8")
    return (data[6] << 8) | data[7]


def find(profile: DeviceProfile = PROFILES["ccam_atis"], serial: int | None = None,
         backend=None):
    """The first matching ``usb.core.Device`` (claimed, interface 0), or raise CameraError.

    With ``serial``, every device with the profile's IDs is opened and asked for its serial
    (CCam only) until one matches; the others are released again."""
    try:
        devs = list(usb.core.find(find_all=True, idVendor=profile.vid, idProduct=profile.pid,
                                  backend=backend))
    except usb.core.NoBackendError:
        raise CameraError("no libusb backend for pyusb: install libusb-1.0 "
                          "(apt install libusb-1.0-0; docs/hardware.md)") from None
    if not devs:
        raise CameraError(f"no {profile.name} device (VID 0x{profile.vid:04X} PID "
                          f"0x{profile.pid:04X}) connected")
    seen = []
    for dev in devs:
        try:
            dev.set_configuration()
            usb.util.claim_interface(dev, INTERFACE)
            if serial is None:
                return dev
            s = read_serial(dev)
            seen.append(s)
            if s == serial:
                return dev
        except usb.core.USBError as e:
            seen.append(f"error {e}")
        usb.util.dispose_resources(dev)
    raise CameraError(f"no {profile.name} with serial {serial}; found {seen}")


class Camera:
    """One opened camera.  Not thread-safe by design: exactly one thread (the reader) calls
    every method; others queue commands to it (firmware_sim.reader)."""

    def __init__(self, dev, profile: DeviceProfile = PROFILES["ccam_atis"]):
        self.dev = dev
        self.profile = profile
        self.biases = default_biases()
        self.serial = None
        ep = usb.util.find_descriptor(dev.get_active_configuration()[(INTERFACE, 0)],
                                      bEndpointAddress=profile.ep_in)
        if ep is None:
            raise CameraError(f"{profile.name}: bulk IN endpoint 0x{profile.ep_in:02X} not found")
        self.max_packet = int(ep.wMaxPacketSize)
        if TRANSFER_BYTES % self.max_packet:
            raise CameraError(f"transfer size {TRANSFER_BYTES} is not a multiple of "
                              f"wMaxPacketSize {self.max_packet}")

    @classmethod
    def open(cls, profile: DeviceProfile | str = "ccam_atis", serial: int | None = None,
             backend=None, biases: dict | None = None, start: bool = True) -> "Camera":
        profile = PROFILES[profile] if isinstance(profile, str) else profile
        cam = cls(find(profile, serial, backend), profile)
        if profile.configure:
            cam.serial = read_serial(cam.dev)
            cam.configure(biases or {})
            if start:
                cam.start()
        return cam

    # ---- control (vendor requests) -----------------------------------------------
    def command(self, register: int, value: int) -> None:
        self.dev.ctrl_transfer(REQ_COMMAND[0], REQ_COMMAND[1], register, 0,
                               struct.pack(">I", value), CTRL_TIMEOUT_MS)

    def _pair(self, cmds) -> None:
        for reg, val in cmds:
            self.command(reg, val)

    def load_biases(self, values: dict) -> None:
        """Validate and send the full bias set (requests 0x61 then 0x62), then flush."""
        full = check_biases({**self.biases, **values})
        payload = bias_payload(full)
        self.dev.ctrl_transfer(REQ_BIAS_A[0], REQ_BIAS_A[1], 0, 0, payload, CTRL_TIMEOUT_MS)
        self.dev.ctrl_transfer(REQ_BIAS_B[0], REQ_BIAS_B[1], 0, 0, payload, CTRL_TIMEOUT_MS)
        self._pair(CMD_FLUSH_BIASES)
        self.biases = full

    def configure(self, biases: dict) -> None:
        self._pair(CMD_ROLE)
        self.load_biases(biases)
        self._pair(CMD_SET_MODE)
        drain = array.array("B", bytes(1024))
        try:                                   # the driver drains one read before starting
            self.dev.read(self.profile.ep_in, drain, 100)
        except usb.core.USBTimeoutError:
            pass

    def start(self) -> None:
        self._pair(CMD_START)

    def stop(self) -> None:
        self._pair(CMD_STOP)

    # ---- data ----------------------------------------------------------------------
    def read_into(self, buf: array.array, timeout_ms: int = READ_TIMEOUT_MS) -> int:
        """One bulk read into ``buf`` (no copy); 0 on timeout.  USBError propagates:
        errno 19 (ENODEV) = disconnected, 32 (EPIPE) = stall (call :meth:`clear_halt`)."""
        if len(buf) % self.max_packet:
            raise CameraError(f"bulk read of {len(buf)} bytes: not a multiple of "
                              f"wMaxPacketSize {self.max_packet}")
        try:
            return self.dev.read(self.profile.ep_in, buf, timeout_ms)
        except usb.core.USBTimeoutError:
            return 0

    def clear_halt(self) -> None:
        self.dev.clear_halt(self.profile.ep_in)

    def close(self) -> None:
        """Stop the camera's stream, then release it: the next open starts a fresh stream
        of whole words instead of the rest of this one (a word cut at a transfer's end
        would otherwise misalign every later word once the host dropped its half)."""
        try:
            self.stop()
        except (usb.core.USBError, ValueError):
            pass                               # already gone (disconnect)
        try:
            usb.util.release_interface(self.dev, INTERFACE)
        except (usb.core.USBError, ValueError):
            pass                               # already gone (disconnect)
        usb.util.dispose_resources(self.dev)


def is_disconnect(e: BaseException) -> bool:
    return isinstance(e, usb.core.USBError) and e.errno == errno.ENODEV


def is_stall(e: BaseException) -> bool:
    return isinstance(e, usb.core.USBError) and e.errno == errno.EPIPE
