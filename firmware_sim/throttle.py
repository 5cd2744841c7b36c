"""``Throttle``: at most one log line of a kind per interval, for the firmware program's
stderr (link events, supervision reports, USB state changes).  A line that comes too soon
is not shown but counted, and the next line of its kind says how many were not shown.
Every event is also counted in STATS, so nothing is lost by throttling the log."""
from __future__ import annotations

import time

LOG_EVERY_S = 1.0                   # at most one log line of a kind per second


class Throttle:
    def __init__(self, every_s: float = LOG_EVERY_S):
        self.every_s = every_s
        self._last: dict[str, list] = {}    # kind -> [time shown, not shown since]

    def __call__(self, kind: str, text: str) -> str | None:
        """``text`` to show now (with the count of lines of ``kind`` not shown before it),
        or None if a line of that kind was shown less than ``every_s`` ago."""
        now = time.monotonic()
        last = self._last.setdefault(kind, [-1e9, 0])
        if now - last[0] < self.every_s:
            last[1] += 1
            return None
        more = f" ({last[1]} more like it not shown)" if last[1] else ""
        last[0], last[1] = now, 0
        return text + more

    def unshown(self) -> list[str]:
        """At the end: one line per kind with lines not shown since its last one."""
        out = [f"{kind}: {n} more line(s) not shown" for kind, (_, n) in self._last.items() if n]
        for last in self._last.values():
            last[1] = 0
        return out
