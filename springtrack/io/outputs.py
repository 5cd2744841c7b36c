"""Text outputs of the command line (track CSV, learned model): a path, or ``-`` for
standard output.

With ``-`` the output owns standard output: the program's own messages (summaries,
``print``) go to standard error for as long as it is open and after, so that the data
stays clean for a pipe.  SIGTERM (``springtrack.process_end.Terminated``) while an output
is open ends it with a last line ``# INCOMPLETE: ...`` (the lines above it are whole), and
a message on standard error names the file.
"""
from __future__ import annotations

import os
import sys
from contextlib import contextmanager

from ..process_end import Terminated

INCOMPLETE_MARK = "# INCOMPLETE"


def is_stdout(path) -> bool:
    return str(path) == "-"


@contextmanager
def text_output(path, what: str = "output"):
    """An open text file for ``path`` (``-``: standard output, see the module docstring)."""
    if is_stdout(path):
        f = os.fdopen(os.dup(sys.stdout.fileno()), "w", newline="")
        sys.stdout.flush()
        sys.stdout = sys.stderr
        name = "standard output"
    else:
        f = open(path, "w", newline="")
        name = str(path)
    try:
        yield f
    except Terminated:
        try:
            f.write(f"\n{INCOMPLETE_MARK}: the {what} was cut short by SIGTERM; the lines "
                    f"above are whole\n")
        finally:
            print(f"{name}: the {what} is incomplete (SIGTERM): marked by its last line "
                  f"'{INCOMPLETE_MARK}: ...'", file=sys.stderr)
        raise
    finally:
        try:
            f.close()
        except BrokenPipeError:
            pass
