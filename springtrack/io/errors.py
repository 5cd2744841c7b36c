"""The exceptions for input that cannot be decoded at all: files and streams of events
(DecodeError), the host link's frames and payloads (WireError)."""


class DecodeError(ValueError):
    """A file or stream is not in a supported format, or its header is unusable.

    Recoverable problems inside a stream (garbage words, events outside the geometry,
    time jumps) are not raised: they are counted in :class:`DecodeStats`.
    """


class WireError(ValueError):
    """A frame or payload of the host link could not be decoded; the message says what and
    where."""
