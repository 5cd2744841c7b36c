"""NAME=VALUE tracker parameters given to the benchmark scripts (--param)."""
from __future__ import annotations

import sys


def parse_params(items) -> dict:
    """NAME=VALUE strings -> {name: int, float or str value}."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep:
            sys.exit(f"--param: expected NAME=VALUE, got {item!r}")
        for conv in (int, float, str):
            try:
                out[name] = conv(value)
                break
            except ValueError:
                pass
    return out
