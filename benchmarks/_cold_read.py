"""One read of an event file in this (fresh) process, timed: the cold-process figure of
benchmarks/decoders.py.  The decoder's modules are imported and it reads ``small`` (the
same format) first, so that the time is the read's alone, with output memory this process
has never touched.

    python benchmarks/_cold_read.py ours|expelliarmus|faery|evt3 evt2|evt3 PATH SMALL WIDTH HEIGHT
    -> prints "<seconds> <events>"
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def reader(who: str, fmt: str, dims):
    if who == "ours":
        import springtrack.io as sio
        return lambda path: sio.open(path).read()
    if who == "expelliarmus":
        from expelliarmus import Wizard
        return Wizard(encoding=fmt).read
    from decoders import faery_read
    if who == "faery":
        return lambda path: faery_read(path, dims)
    import evt3
    return lambda path: evt3.decode_file(str(path))


def main():
    who, fmt, path, small, width, height = sys.argv[1:7]
    read = reader(who, fmt, (int(width), int(height)))
    read(small)
    t0 = time.perf_counter()
    n = len(read(path))
    print(f"{time.perf_counter() - t0:.6f} {n}")


if __name__ == "__main__":
    main()
