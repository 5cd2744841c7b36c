"""A simulated CCam ATIS (or Prophesee EVT board) as a real pyusb backend.

    from firmware_sim.simcam import SimBackend, SimCamera
    from firmware_sim.sources import events_source
    backend = SimBackend(SimCamera(events_source(events), realtime=False))
    dev = usb.core.find(idVendor=0x04B4, idProduct=0x00F4, backend=backend)

One job per module:

* ``words``   - what the device sends: event arrays encoded as chunks of words with
  release marks, per word format (``ENCODERS``), and the noise burst of the faults;
* ``device``  - :class:`SimCamera`, the device: clock, FIFO, vendor requests, faults;
* ``backend`` - :class:`SimBackend`, the ``usb.backend.IBackend`` pyusb talks to.

Where the events come from (a scene, a replayed file, an array) is
``firmware_sim.sources``' job; ``firmware-sim run --source URL`` picks one by URL.
"""
from .backend import SimBackend
from .device import SimCamera

__all__ = ["SimBackend", "SimCamera"]
