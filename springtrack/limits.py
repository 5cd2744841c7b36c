"""Compile-time capacities of the C kernels (mirrored by ``cdef enum`` in ``_kernel.pxd``;
a test checks that the two agree)."""
MAX_TRACKERS = 64
MAX_CONNECTIONS = 128
