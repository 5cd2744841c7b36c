"""Event I/O: streaming decoders, file readers and writers (docs/formats.md)."""
