"""hostctl: steer a springtrack firmware over its host link (serial, USB-CDC, TCP).

Python API: :class:`Device` (a context manager with the same verbs as the ``hostctl``
command); protocol: :mod:`springtrack.wire`, docs/protocol.md.
"""
from .device import (Device, HostctlError, Nacked, NoAnswer, NoSuchPort, Snapshot,
                     VersionMismatch)

__all__ = ["Device", "Snapshot", "HostctlError", "NoSuchPort", "NoAnswer", "VersionMismatch",
           "Nacked"]
