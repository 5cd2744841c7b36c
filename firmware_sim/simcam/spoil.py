"""How the ``corrupt`` fault spoils one event word of each word format the simulated camera
streams (``SPOILERS``, by ``firmware_sim.camera.DeviceProfile.fmt``).

A spoiler knows its format's word size (``unit`` bytes), which words carry events, and
two ways to spoil such a word in place, both of which the decoders must count rather than
track: ``unknown`` (the word type made one the format does not define: the decoder's
``unknown_type``) and ``outside`` (a coordinate made one no sensor of that format has,
2047 or 255: ``out_of_geometry``, one per event the word carried).  Words that carry no
event (time bases, triggers, vector bases, continuations) are left alone so that the
stream's time stays decodable and the counts stay exact.

Field layouts: ``springtrack/io/ccam_types.h``, ``evt2_types.h``, ``evt21_types.h``,
``evt3_types.h`` (named as in OpenEB).
"""
from __future__ import annotations


class CcamWords:
    """CCam ATIS 32-bit words: type in byte 3 (0x80 time high), row in byte 0."""
    unit = 4

    def events(self, w: memoryview) -> int:
        return 0 if w[3] == 0x80 else 1

    def unknown(self, w: memoryview) -> None:
        w[3] = 0xC0                                      # undefined word type

    def outside(self, w: memoryview) -> None:
        w[0] = 0xFF                                      # row 255: below any CCam sensor


class Evt2Words:
    """EVT 2.0 32-bit little-endian words: type in bits 31..28 (CD_OFF 0x0, CD_ON 0x1),
    y in bits 10..0."""
    unit = 4

    def events(self, w: memoryview) -> int:
        return 1 if w[3] >> 4 in (0x0, 0x1) else 0

    def unknown(self, w: memoryview) -> None:
        w[3] = (w[3] & 0x0F) | 0x50                      # type 0x5: undefined in EVT 2.0

    def outside(self, w: memoryview) -> None:
        w[0] = 0xFF                                      # y = 2047
        w[1] |= 0x07


class Evt21Words:
    """EVT 2.1 64-bit little-endian words: type in bits 63..60 (EVT_NEG 0x0, EVT_POS 0x1),
    y in bits 42..32, the valid mask in bits 31..0 (one event per set bit); ``legacy``
    (the IMX636 order): the two 32-bit halves swapped."""
    unit = 8

    def __init__(self, legacy: bool = False):
        self.hi, self.lo = (0, 4) if legacy else (4, 0)   # byte offsets of the halves

    def events(self, w: memoryview) -> int:
        if w[self.hi + 3] >> 4 not in (0x0, 0x1):
            return 0
        return sum(bin(b).count("1") for b in w[self.lo:self.lo + 4])

    def unknown(self, w: memoryview) -> None:
        w[self.hi + 3] = (w[self.hi + 3] & 0x0F) | 0x50  # type 0x5: undefined in EVT 2.1

    def outside(self, w: memoryview) -> None:
        w[self.hi] = 0xFF                                # y = 2047
        w[self.hi + 1] |= 0x07


class Evt3Words:
    """EVT 3.0 16-bit little-endian words: type in bits 15..12; only EVT_ADDR_X (0x2, one
    event at the current row, x in bits 10..0) is spoiled: a vector word's events depend
    on the base before it."""
    unit = 2

    def events(self, w: memoryview) -> int:
        return 1 if w[1] >> 4 == 0x2 else 0

    def unknown(self, w: memoryview) -> None:
        w[1] = (w[1] & 0x0F) | 0x90                      # type 0x9: undefined in EVT 3.0

    def outside(self, w: memoryview) -> None:
        w[0] = 0xFF                                      # x = 2047
        w[1] |= 0x07


SPOILERS = {
    "ccam": lambda legacy=False: CcamWords(),
    "evt2": lambda legacy=False: Evt2Words(),
    "evt21": lambda legacy=False: Evt21Words(legacy),
    "evt3": lambda legacy=False: Evt3Words(),
}
