"""Helpers for benchmarks: machine description and docs section updates."""
from __future__ import annotations

import os
import platform
import re
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md"


def cpu_info() -> tuple[str | None, float | None, set[str]]:
    """The first processor's model name, clock (MHz) and flags from /proc/cpuinfo (None,
    None, empty where it is not readable)."""
    model, mhz, flags = None, None, set()
    try:
        for line in open("/proc/cpuinfo"):
            key, _, val = line.partition(":")
            key = key.strip()
            if key == "model name" and model is None:
                model = val.strip()
            elif key == "cpu MHz" and mhz is None:
                mhz = float(val)
            elif key == "flags" and not flags:
                flags = set(val.split())
    except OSError:
        pass
    return model, mhz, flags


def machine() -> str:
    """CPU model, clock, widest vector extension (the kernels' vectorised passes pick their
    clone by it, so it matters as much as the clock), cores, Python, OS."""
    model, mhz, flags = cpu_info()
    model = model or platform.processor() or "unknown CPU"
    vec = next((v for v in ("avx512f", "avx2", "sse2") if v in flags), None)
    clock = f" at {mhz / 1000:.2f} GHz" if mhz else ""
    isa = f", {vec.upper()}" + (" (no AVX-512)" if vec == "avx2" else "") if vec else ""
    return (f"{model}{clock}{isa}, {os.cpu_count()} cores, Python {platform.python_version()}, "
            f"{platform.system()}")


def replace_section(path: Path, title: str, body: str, new_doc: str = "") -> None:
    """Replace (or append) the ``## title`` section of the markdown file ``path`` (made
    from ``new_doc`` if it does not exist)."""
    text = path.read_text() if path.exists() else new_doc
    block = f"## {title}\n\n{body.strip()}\n"
    pat = re.compile(rf"^## {re.escape(title)}\n.*?(?=^## |\Z)", re.S | re.M)
    if pat.search(text):
        text = pat.sub(block + "\n", text)
    else:
        text = text.rstrip() + "\n\n" + block
    path.write_text(text.rstrip() + "\n")


def write_section(title: str, body: str) -> None:
    """Replace (or append) the ``## title`` section of docs/benchmarks.md."""
    DOC.parent.mkdir(exist_ok=True)
    replace_section(DOC, title, body,
                    "# Benchmarks\n\nNumbers written by the scripts in `benchmarks/`.\n")
