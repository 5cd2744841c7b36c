"""Live event sources by URL, as pyserial maps port URLs to handler modules.

    reader = springtrack.live.open("dv://127.0.0.1:7777")   # or springtrack.io.open(url)
    for chunk in reader: ...                                 # EVENT_DTYPE arrays, as they come
    reader.stats                                             # events, batches, gaps, why it ended

A URL is ``SCHEME:TARGET``.  :data:`SCHEMES` maps each scheme to the module that handles
it, imported only when a URL names it; a handler module defines ``USAGE``
(``"udp://HOST:PORT"``), ``HELP`` (one line) and ``open(target, url) -> LiveReader``.
:func:`register` adds one without editing any caller.  ``springtrack.io.open`` hands every
URL of a registered scheme here, so ``springtrack track``, ``learn``, ``render`` and
``info`` read live streams as they read files, and ``firmware-sim run --source`` serves
them through its simulated camera (``firmware_sim.sources`` delegates these schemes).

The library only reads streams: it knows no device of its own and no host (docs/live.md).
"""
from __future__ import annotations

import importlib
import textwrap

from .base import LiveReader, LiveStats, StreamOptionError

# scheme -> handler module
SCHEMES: dict[str, str] = {
    "dv": "springtrack.live.dv",
    "udp": "springtrack.live.udp",
}

__all__ = ["SCHEMES", "LiveReader", "LiveStats", "StreamOptionError", "register", "handler",
           "scheme_of", "is_live", "usage", "describe", "open"]


def register(scheme: str, module: str) -> None:
    """Serve ``scheme:TARGET`` URLs with handler ``module`` (an importable module name)."""
    SCHEMES[scheme] = module


def scheme_of(name) -> str | None:
    """The registered scheme ``name`` starts with (``"dv"`` for ``dv://h:p``), else None
    (a file path)."""
    if not isinstance(name, str):
        return None
    scheme, sep, _ = name.partition(":")
    return scheme if sep and scheme in SCHEMES else None


def is_live(name) -> bool:
    """Whether ``name`` is a live source URL rather than a file path."""
    return scheme_of(name) is not None


def handler(scheme: str):
    if scheme not in SCHEMES:
        raise ValueError(f"unknown live source scheme {scheme!r}; use {usage()}")
    return importlib.import_module(SCHEMES[scheme])


def usage() -> str:
    """The URL forms of every registered scheme: ``dv://HOST:PORT | ... | udp://HOST:PORT``."""
    return " | ".join(handler(s).USAGE for s in SCHEMES)


def describe(indent: int = 0, width: int = 88) -> str:
    """A help paragraph per registered scheme, ``indent`` spaces in from the second line."""
    pad = " " * indent
    return "\n".join(textwrap.fill(f"{handler(s).USAGE}: {handler(s).HELP}", width,
                                   subsequent_indent=pad + "  ", initial_indent=pad
                                   ).removeprefix(pad if i == 0 else "")
                     for i, s in enumerate(SCHEMES))


def open(url: str) -> LiveReader:            # noqa: A001 (the module's verb, as io.open)
    """The live stream ``url`` names, connected (ValueError, ConnectionError or
    ImportError naming the extra to install, saying what is wrong)."""
    scheme = scheme_of(url)
    if scheme is None:
        raise ValueError(f"{url!r} is not a live source URL; use {usage()}")
    return handler(scheme).open(url[len(scheme) + 1:], url)
