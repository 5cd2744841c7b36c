"""The tracking loop's feed for a kernel the fused loop cannot call (the microcontroller
build in its emulator, which has no C-level step): ``firmware_sim._fused.Fused``'s
interface over a ``springtrack.io`` streaming decoder and the kernel's own ``run``."""
from __future__ import annotations

import numpy as np

from springtrack.sampling import UNSET, first_sample_time, multiples

from . import camera as camusb


class DecodedFeed:
    """The non-fused path, for a kernel with no C-level step (the microcontroller build in
    its emulator), with the interface of ``_fused.Fused``: a ``springtrack.io`` streaming
    decoder of the profile's words (any format the fused loop decodes) turns each piece
    into an event array, then the kernel's own ``run`` tracks it with the same sampling
    rule, its rows carrying the TELEMETRY records it packs.  One Python call per piece,
    never per event."""

    def __init__(self, kernel, period_us: int, profile):
        self.profile = profile
        self.decoder = camusb.make_decoder(profile)
        self.kernel = kernel
        self.period = int(period_us)
        self.next_t = UNSET
        self.first_t = -1
        self.mark = False
        self.tracked = 0
        self.samples_skipped = 0      # sample times of empty stretches not taken
        self.bytes_in = 0
        self.gaps = 0
        self.old_words = 0            # counts of decoders replaced after gaps
        self.old_events = 0

    @property
    def kernel_obj(self):
        return self.kernel

    @property
    def native_records(self):
        """The sample rows carry the kernel's own TELEMETRY records (the microcontroller
        build packs them; the host kernels' ``run`` returns float rows)."""
        return getattr(self.kernel, "native_records", False)

    @property
    def last_t(self):
        return self.kernel.last_t

    def set_kernel(self, kernel) -> None:
        self.kernel = kernel
        self.mark_next()

    def mark_next(self) -> None:
        self.mark = True
        self.first_t = -1

    def _track(self, ev):
        return self.kernel.run(ev, self.period, self.next_t, 512)

    def gap(self) -> None:
        """Data lost: restart the decoder (its time base and partial word are stale);
        events it emits before a fresh time base go back in time and the kernel skips and
        counts them."""
        st = self.decoder.stats
        self.old_words += st.words
        self.old_events += st.events
        self.decoder = camusb.make_decoder(self.profile)
        self.gaps += 1

    def feed(self, buf, n: int = -1, sink=None):
        """As ``_fused.Fused.feed``: the snapshots taken, or each block of them passed to
        ``sink`` as it is taken (memory bounded by one block) and None returned."""
        mv = memoryview(buf).cast("B")
        if n >= 0:
            mv = mv[:n]
        self.bytes_in += len(mv)
        return self.track(self.decoder.decode(mv), sink)

    def track(self, ev, sink=None):
        """Track decoded events ``ev``: their sample rows (None if none), or each block of
        them passed to ``sink`` (as :meth:`feed`)."""
        if len(ev) == 0:
            return None
        if self.mark:
            self.mark = False
            self.first_t = int(ev["t"][0])
        parts, pos = [], 0
        while pos < len(ev):
            start = self.next_t
            if start == UNSET and self.period > 0:
                start = first_sample_time(int(ev["t"][pos]), self.period)
            consumed, self.next_t, out = self._track(ev[pos:])
            pos += consumed
            taken = 0 if out is None else len(out["t"])
            if self.period > 0 and self.next_t != UNSET:     # the sample times passed over
                self.samples_skipped += multiples(start, self.next_t, self.period) - taken
            if taken:
                if sink is not None:
                    sink(out)
                else:
                    parts.append(out)
        self.tracked += len(ev)
        return join_samples(parts)

    def counters(self) -> dict:
        st = self.decoder.stats
        kc = self.kernel.counters()
        an = {k: int(v) for k, v in st.anomalies.items()}
        an.update(tracker_back_in_time=kc["skipped_back_in_time"],
                  tracker_outside_sensor=kc["skipped_outside_sensor"])
        an.setdefault("skipped_after_gap", 0)
        return dict(format=self.profile.fmt, words=self.old_words + st.words,
                    time_high_words=st.info.get("time_high_words", 0),
                    events_decoded=self.old_events + st.events,
                    exposure_events=st.info.get("exposure_events", 0),
                    events_tracked=self.tracked, time_wraps=st.info.get("time_wraps", 0),
                    gaps=self.gaps, bytes=self.bytes_in, pending_bytes=st.pending_bytes,
                    triggers=st.info.get("triggers", 0), other_words=st.info.get("other_words", 0),
                    time_low_backwards=st.info.get("time_low_backwards", 0), outside_roi=0,
                    samples_skipped=self.samples_skipped, anomalies=an)


def join_samples(parts):
    """Sample blocks (dicts of arrays; None entries skipped) as one, None if none."""
    parts = [q for q in parts if q is not None]
    if not parts:
        return None
    return parts[0] if len(parts) == 1 else {k: np.concatenate([q[k] for q in parts])
                                              for k in parts[0]}
