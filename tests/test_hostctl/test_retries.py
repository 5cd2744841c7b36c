"""hostctl's retries, counted on the wire: a command no device answers is sent exactly
``retries + 1`` times, each a repeat of the same frame's sequence number."""
import pytest

from firmware_sim import transport
from hostctl import Device, NoAnswer
from springtrack import wire
from springtrack.wire import MsgType


@pytest.mark.parametrize("retries", [0, 1, 3])
def test_a_silent_device_is_asked_exactly_retries_plus_one_times(retries):
    pty = transport.PtyPort()                           # nobody answers on it
    try:
        with pytest.raises(NoAnswer, match=f"after {retries + 1} tries of 0.05 s"):
            Device(pty.path, timeout=0.05, retries=retries)
        pty.timeout = 0.2
        frames = wire.FrameReader().feed(pty.read(65536))
        hellos = [f for f in frames if f.type == MsgType.HELLO]
        assert len(hellos) == retries + 1, [f.type for f in frames]
        assert len({f.seq for f in hellos}) == 1        # a retry repeats its sequence number
    finally:
        pty.close()
