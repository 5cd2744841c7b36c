"""The one registry of tracker backends: name -> :class:`BackendSpec`.

``Tracker(backend=...)``, ``springtrack track --backend``, ``firmware-sim run --backend``
and the firmware's model slot all read it.  A name may carry an option after a colon
(``"mcu:cortex-m7"``: the core) when its spec has ``option``.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable

from ..instances import ModelSet

DEFAULT_BACKEND = "cython"


@dataclass(frozen=True)
class BackendSpec:
    name: str
    help: str                       # one phrase for --help
    build: Callable                 # (model or ModelSet, params, option) -> Backend
    firmware: bool                  # firmware_sim's loop runs it (a C step or an emulator)
    reads_layouts: bool             # its C loop reads the common event layouts as they are
    integer: bool                   # the fixed kernel's Q formats bound its parameters
    option: str = ""                # what NAME:OPTION names ("" : no option)


def _cython(model, params, option):
    from ..kernel.kernel import Kernel
    return Kernel(model, params)         # one ShapeModel or a ModelSet


def _reference(model, params, option):
    from .reference import ReferenceBackend
    return ReferenceBackend(model, params)


def _fixed(model, params, option):
    try:
        mod = importlib.import_module("springtrack.fixed.kernel")
    except ImportError as e:
        raise ValueError(f"backend 'fixed' is not available in this build: {e}") from None
    if isinstance(model, ModelSet):                       # one fx_state per instance
        return mod.FixedSet(model if params is None else model.with_params(params))
    return mod.FixedKernel(model, params)


def _mcu(model, params, option):
    from ..mcu import MissingExtra
    try:
        from ..mcu.backend import DEFAULT_TARGET, McuBackend, McuSet
        if isinstance(model, ModelSet):                   # one fx_state per instance
            return McuSet(model if params is None else model.with_params(params),
                          target=option or DEFAULT_TARGET)
        return McuBackend(model, params, target=option or DEFAULT_TARGET)
    except (MissingExtra, RuntimeError) as e:      # no toolchain, a failed build or run
        raise ValueError(f"backend 'mcu': {e}") from None


BACKENDS: dict[str, BackendSpec] = {s.name: s for s in (
    BackendSpec("cython", "fast float64 kernel (default)", _cython,
                firmware=True, reads_layouts=True, integer=False),
    BackendSpec("reference", "the pure-Python specification (slow)", _reference,
                firmware=False, reads_layouts=False, integer=False),
    BackendSpec("fixed", "integer-only kernel (docs/fixed_point.md; positions Q.32 px)", _fixed,
                firmware=True, reads_layouts=True, integer=True),
    BackendSpec("mcu", "that kernel's microcontroller build run in an emulator (same output "
                "as fixed, slowly; docs/mcu.md; needs pip install 'springtrack[mcu]')", _mcu,
                firmware=True, reads_layouts=False, integer=True, option="core"),
)}


def backend_names(firmware: bool = False) -> list[str]:
    """The backends' names (``firmware``: those the firmware loop runs), in registry order."""
    return [n for n, s in BACKENDS.items() if s.firmware or not firmware]


def backend_help(firmware: bool = False) -> str:
    """``--backend``'s help: each name with its phrase."""
    return "; ".join(f"{n}: {BACKENDS[n].help}" for n in backend_names(firmware))


def spec_of(name: str, firmware: bool = False) -> tuple[BackendSpec, str]:
    """(spec, option) of ``name`` ("mcu:cortex-m7" -> the mcu spec, "cortex-m7");
    ValueError naming the choices for an unknown name or an option its backend takes none of."""
    base, _, option = name.partition(":")
    spec = BACKENDS.get(base)
    if firmware and (spec is None or not spec.firmware):
        raise ValueError(f"backend {name!r}: the firmware runs one of "
                         f"{', '.join(backend_names(firmware=True))}")
    if spec is None or (option and not spec.option):
        raise ValueError(f"unknown backend {name!r}; choose from {', '.join(BACKENDS)} "
                         f"(mcu:TARGET names a core)")
    return spec, option


def make_backend(name: str, model, params):
    """The backend ``name`` over ``model`` (a ShapeModel with its Params, or a ModelSet with
    params None)."""
    spec, option = spec_of(name)
    return spec.build(model, params, option)


def check_backend_params(name: str, model, params) -> None:
    """ValueError if backend ``name`` would refuse ``params`` for ``model``: the checks its
    ``set_params`` runs before loading them (an integer backend's Q formats,
    ``springtrack.fixed.q.params_words``), so that an accepted update always applies."""
    if spec_of(name)[0].integer:
        from ..fixed.q import params_words
        params_words(params, len(model.connections))
