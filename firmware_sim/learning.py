"""The tracking loop's feed when the model is learned from the stream's start
(``firmware-sim run --learn-first-ms``): ``springtrack.learning.learner`` on the first milliseconds
of the camera's events, then tracking with the learned model from where the window ended.

The learning window needs decoded events, which the fused loop never materialises, so
this feed is the decoded path (``firmware_sim.feed.DecodedFeed``: a ``springtrack.io``
streaming decoder of the profile's words, then the kernel's own ``run``) with a first
phase that holds the window's events instead of tracking them.  The learner runs in the
processing thread once the window is complete (about half a second of CPU per second of
a face's events); meanwhile the reader keeps filling its buffers (at ``--realtime`` it
sheds transfers it cannot queue, and counts them).
"""
from __future__ import annotations

import numpy as np

from springtrack.events import EVENT_DTYPE

from .feed import DecodedFeed


class LearningFeed(DecodedFeed):
    """``LearningFeed(kernel, period_us, profile, ms, width, height, track_params=None,
    learner=None)`` (``learner``: the learner's parameter overrides, LearnParams names):
    :class:`DecodedFeed` whose events of ``[t0, t0 + ms)`` (t0 the first event's time)
    are held, not tracked; then ``learned`` holds the ``springtrack.learning.learner.LearnResult``
    (``error`` the message if nothing was found: then nothing is tracked, the events are
    counted, ``events_untracked``, until a host uploads a model), which the loop loads as
    its model (:meth:`set_kernel`) before tracking the events after the window
    (:meth:`track_rest`).  A model set before the window is complete (a host's upload)
    ends the learning: the held events are dropped and counted (``events_unlearned``)."""

    def __init__(self, kernel, period_us: int, profile, ms: float, width: int, height: int,
                 track_params: dict | None = None, learner: dict | None = None):
        if not ms > 0:
            raise ValueError(f"--learn-first-ms must be positive, got {ms}")
        super().__init__(kernel, period_us, profile)
        self.window_us = int(round(ms * 1000))
        self.width, self.height = int(width), int(height)
        self.track_params = track_params
        self.learner_params = learner
        self.learning = True
        self.t_end = None
        self.held: list = []
        self.n_held = 0
        self.rest = np.empty(0, EVENT_DTYPE)     # decoded after the window, not tracked yet
        self.learned = None                      # LearnResult once learned
        self.error = ""                          # why nothing was learned
        self.events_learned = 0
        self.events_unlearned = 0
        self.events_untracked = 0                # after a window with no object
        self.idle = False                        # nothing learned, no model uploaded since

    def set_kernel(self, kernel) -> None:
        if self.learning:                        # a model from elsewhere ends the learning
            self.learning = False
            self.events_unlearned += self.n_held
            self.held, self.n_held = [], 0
        self.idle = False
        super().set_kernel(kernel)

    def feed(self, buf, n: int = -1, sink=None):
        if not self.learning and not self.idle:
            return super().feed(buf, n, sink)
        mv = memoryview(buf).cast("B")
        if n >= 0:
            mv = mv[:n]
        self.bytes_in += len(mv)
        ev = self.decoder.decode(mv)
        if self.idle:                            # nothing learned: nothing to track
            self.events_untracked += len(ev)
            return None
        if len(ev) == 0:
            return None
        if self.t_end is None:
            self.t_end = int(ev["t"][0]) + self.window_us
        k = int(np.searchsorted(ev["t"], self.t_end, side="left"))
        self.held.append(ev[:k].copy())
        self.n_held += k
        if k < len(ev):
            self.rest = ev[k:].copy()
            self._learn()
        return None

    def track_rest(self, sink=None):
        """Track the events decoded after the window (with the learned model, once the
        loop has set its kernel): their sample rows, or each block passed to ``sink``."""
        ev, self.rest = self.rest, np.empty(0, EVENT_DTYPE)
        return self.track(ev, sink)

    def _learn(self) -> None:
        """The window is complete: learn (``learned``, or ``error`` and the events after
        the window are counted, not tracked)."""
        from springtrack.learning.learner import NoObjectFound, learn_model
        events = np.concatenate(self.held) if self.held else np.empty(0, EVENT_DTYPE)
        self.held, self.n_held = [], 0
        self.events_learned = len(events)
        self.learning = False
        try:
            self.learned = learn_model(events, width=self.width, height=self.height,
                                       name="learned", params=self.learner_params,
                                       track_params=self.track_params)
        except NoObjectFound as e:
            self.error = str(e)
            self.idle = True
            self.events_untracked += len(self.rest)
            self.rest = np.empty(0, EVENT_DTYPE)

    def counters(self) -> dict:
        c = super().counters()
        c.update(learning=self.learning, events_learned=self.events_learned + self.n_held,
                 events_unlearned=self.events_unlearned, events_untracked=self.events_untracked)
        return c

