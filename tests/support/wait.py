"""``wait_for``: the one deadline loop of the tests."""
from __future__ import annotations

import time


def wait_for(cond, timeout: float = 30.0, what: str = "the condition", interval: float = 0.01):
    """Poll ``cond()`` every ``interval`` s until it returns a true value, and return that
    value; AssertionError naming ``what`` after ``timeout`` s (generous: the machine may be
    loaded; a test that passes never waits that long)."""
    end = time.monotonic() + timeout
    while True:
        got = cond()
        if got:
            return got
        if time.monotonic() >= end:
            raise AssertionError(f"{what} not reached within {timeout:g} s")
        time.sleep(interval)


def wait_drained(cam, eng, timeout: float = 30.0, polls: int = 3) -> None:
    """Wait until a firmware loop ``eng`` has taken everything its simulated camera ``cam``
    served: the camera finished and the loop caught up on ``polls`` polls in a row (20 ms
    apart); AssertionError with the loop's statistics after ``timeout`` s."""
    quiet = [0]

    def settled():
        quiet[0] = quiet[0] + 1 if cam.finished and eng.caught_up() else 0
        return quiet[0] >= polls
    try:
        wait_for(settled, timeout, "the stream's end", interval=0.02)
    except AssertionError:
        raise AssertionError(f"the stream did not end within {timeout:g} s: "
                             f"{eng.stats_line()}") from None
