"""A model upload validated off the host link's thread, within a time and memory budget.

The link keeps answering every session while a :class:`Validation` parses an uploaded
text in its own thread.  Its cost is bounded before it starts: the text is at most
``toml_bounds.MAX_TEXT_BYTES`` and passes :func:`springtrack.toml_bounds.check` (linear,
constant memory) before ``tomllib`` sees it, so the parser's time and memory are bounded
by those limits (docs/firmware.md, "Model uploads"); at most one validation runs per
firmware (a second upload meanwhile is refused BUSY).  A validation that has not finished
within ``BUDGET_S`` is refused (BUSY) and its result discarded.  What the thread hands
back is the model's canonical text (``ShapeModel.to_toml``, a few KB at most), which the
engine then loads on the link's thread as before.
"""
from __future__ import annotations

import threading
import time

from springtrack import model as _model
from springtrack.wire import Nack

from .engine import UpdateRejected
from .slot import _model_code, _reason

BUDGET_S = 1.5          # below the host's 4 tries x 0.5 s of waiting for the answer


class Validation:
    """``Validation(text)`` starts validating the uploaded ``text`` at once; ``done`` is set
    when it has finished, then ``canonical`` (str) or ``error`` (UpdateRejected) is set."""

    def __init__(self, text: str, budget_s: float = BUDGET_S):
        self.budget_s = budget_s
        self.deadline = time.monotonic() + budget_s
        self.canonical: str | None = None
        self.error: UpdateRejected | None = None
        self.done = threading.Event()
        threading.Thread(target=self._run, args=(text,), name="model-validation",
                         daemon=True).start()

    def _run(self, text: str) -> None:
        try:
            self.canonical = _model.loads(text, "uploaded model").to_toml()
        except (ValueError, TypeError, RecursionError) as e:   # ModelError is a ValueError
            self.error = UpdateRejected(_model_code(e), _reason(e))
        except Exception as e:                                 # noqa: BLE001 - reported as a NACK
            self.error = UpdateRejected(Nack.INTERNAL, f"validating the model: "
                                                       f"{type(e).__name__}: {e}")
        finally:
            self.done.set()

    def overdue(self, now: float) -> bool:
        return not self.done.is_set() and now > self.deadline

    def result(self) -> str:
        """The canonical model text, or raise why not (the upload's NACK)."""
        if not self.done.is_set():
            raise UpdateRejected(Nack.BUSY, f"validating the uploaded model took longer than "
                                            f"{self.budget_s:g} s: refused")
        if self.error is not None:
            raise self.error
        return self.canonical
