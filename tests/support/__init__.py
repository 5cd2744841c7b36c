"""Test support: helpers and fixtures shared by the test modules (no test module imports
another).  ``REPO`` is the repository root.

* :mod:`.probes` builds and loads the test-only Cython modules (``kernel_probe.pyx``,
  ``fixed_probe.pyx``: kernel internals, never installed);
* :mod:`.wait` ``wait_for``: the one deadline loop;
* :mod:`.fwproc` ``firmware-sim`` and ``hostctl`` as separate processes (HIL tests);
* :mod:`.engine` ``SimEngine``, a small deterministic firmware engine; :mod:`.link`
  ``Served``, a link server on a pty or socket in a thread;
* :mod:`.fused` the fused loop's helpers; :mod:`.words` camera word streams with every
  kind of special word; :mod:`.ticks` coarse-ticked recordings;
* :mod:`.moves`, :mod:`.fixed_bound` (the fixed kernel's documented bound),
  :mod:`.decoder_fuzz`, :mod:`.peak_rss` (a process's peak memory, run as a script);
* :mod:`.equivalence` the rounding-noise excusals of the kernel-vs-reference suite, counted.
"""
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
