"""``usb``: a real camera through pyusb and libusb (docs/hardware.md)."""
from __future__ import annotations

from .. import camera as camusb
from . import CameraSource, SourceOptions, profile

USAGE = "usb"
HELP = ("a real CCam ATIS (or an EVK streaming --profile's words, of --geometry) through "
        "pyusb/libusb, docs/hardware.md")


def open(target: str, opts: SourceOptions, url: str) -> CameraSource:
    if target:
        raise ValueError(f"--source {url!r}: the usb source takes no target (use --serial)")
    if opts.faults:
        raise ValueError("--faults needs a simulated source (sim:SCENE or replay:FILE)")
    prof = profile(opts.profile, *(opts.geometry or (None, None)))

    def open_camera():
        return camusb.Camera.open(prof, opts.serial, biases=opts.biases)
    open_camera().close()                      # fail now, clearly, if there is no camera
    return CameraSource(url, open_camera, profile=prof)
