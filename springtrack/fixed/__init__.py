"""The integer-only tracker kernel (``Tracker(..., backend="fixed")``, docs/fixed_point.md):
``q.py`` (its Q formats: the model and parameter word streams, the generated constant
tables), ``kernel.pyx`` (``FixedKernel``, ``FixedSet``), and its C in ``csrc/``
(``fixed_step.c``, one translation unit of one part per job, shared with the
microcontroller build of springtrack/mcu/; ``fixed_telemetry.c``)."""
