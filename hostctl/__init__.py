"""hostctl: steer a springtrack firmware over its host link (serial, USB-CDC, TCP).

Python API: :class:`Device` (a context manager with the same verbs as the ``hostctl``
command); protocol: :mod:`springtrack.wire`, docs/protocol.md.
"""
from springtrack.wire import Role

from .device import (AuthFailed, Device, HostctlError, Nacked, NoAnswer, NoSuchPort,
                     Snapshot, VersionMismatch)

__all__ = ["Device", "Snapshot", "HostctlError", "NoSuchPort", "NoAnswer", "VersionMismatch",
           "Nacked", "AuthFailed", "Role"]
