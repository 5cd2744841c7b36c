"""Finding the models in the events and keeping them found (docs/acquisition.md):
``acquire.py`` (the pose search of a window: ``acquire``, ``place``, ``Acquisition``;
its inner loops in ``scoring.pyx``), ``spread.py`` (the placed trackers' covariances from
the events), ``loss.py`` (the loss rule, the same for every backend), ``recovery.py``
(``Recovery``: loss checks, verifications, re-acquisition), ``recall.py`` (trackers left
behind by their parts)."""
