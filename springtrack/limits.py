"""Compile-time capacities of the C kernels (mirrored by ``cdef enum`` in ``_kernel.pxd``
and ``FX_MAX_*`` in ``csrc/fixed_step.h``; tests check that they agree).

A model holds at most MAX_TRACKERS trackers and MAX_CONNECTIONS connections; a tracker
holds at most MAX_INSTANCES model instances and MAX_SET_TRACKERS / MAX_SET_CONNECTIONS in
all (springtrack.instances; docs/acquisition.md)."""
MAX_TRACKERS = 64
MAX_CONNECTIONS = 128
MAX_INSTANCES = 16
MAX_SET_TRACKERS = 256
MAX_SET_CONNECTIONS = 512
