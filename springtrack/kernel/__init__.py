"""The float64 tracker kernel (``Tracker(..., backend="cython")``), one module per job:
``kernel.pyx`` (the Python ``Kernel``, its ``Stepper``, the sample row), ``state.pxd``
(``KState``, capacities), ``step.pxd`` (eqs. 2-6, the per-event step), ``index.pxd`` (the
spatial index), ``covariance.pxd`` (eq. 4's clamp and inverse), ``activity.pxd`` (eq. 6),
``springs.pyx`` (eqs. 7-22 and the state guard).  A translation of springtrack/reference.py,
equal to it to 1e-9 px (docs/algorithm.md)."""
