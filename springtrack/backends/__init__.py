"""The tracker backends behind one interface, and the one registry of their names.

* :mod:`.protocol`  ``Backend``: what every backend offers (``springtrack.Tracker``, the
                    acquisition and ``firmware_sim`` call nothing else);
* :mod:`.registry`  ``BACKENDS``: name -> ``BackendSpec`` (help text, factory, whether the
                    firmware loop runs it); ``make_backend("mcu:cortex-m7", model, params)``;
* :mod:`.reference` ``ReferenceBackend``: the specification (springtrack.reference) behind
                    the interface;
* ``stepper.pyx`` / ``samples.pyx``: a kernel seen from a C loop (``Stepper``, the sampled
  event loop ``run_events``) and its sample rows, shared by the float and fixed kernels
  and the firmware's fused loop.

Adding a backend: write its class (the ``Backend`` methods), then one ``BackendSpec`` in
``registry.BACKENDS``; the CLIs (``--backend``), ``Tracker`` and the firmware take it from
there.
"""
from .protocol import Backend
from .registry import (BACKENDS, DEFAULT_BACKEND, BackendSpec, backend_help, backend_names,
                       check_backend_params, make_backend, spec_of)

__all__ = ["Backend", "BACKENDS", "DEFAULT_BACKEND", "BackendSpec", "backend_help",
           "backend_names", "check_backend_params", "make_backend", "spec_of"]
