"""The exception for input that cannot be decoded at all."""


class DecodeError(ValueError):
    """A file or stream is not in a supported format, or its header is unusable.

    Recoverable problems inside a stream (garbage words, events outside the geometry,
    time jumps) are not raised: they are counted in :class:`DecodeStats`.
    """
