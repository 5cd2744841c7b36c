"""Bounds on model and parameter text, checked before it reaches ``tomllib``.

``tomllib``'s cost is not linear in its input: a dotted key of n segments
(``a.a.a...a = 1``) costs time and memory quadratic in n (a 60 KB key: 11 s and 3.5 GB),
each level of arrays or inline tables costs a recursion, and a long array or many keys
cost a Python object each.  :func:`check` scans the text once, in time linear in its
length and constant memory, and refuses text beyond any of the bounds below with an error
naming the bound; text within them parses in bounded time and memory (docs/formats.md,
"Model and parameter text", has the measured worst case).  The bounds are far above what a
valid model needs: at most ``limits.MAX_TRACKERS`` trackers of ~8 values and
``limits.MAX_CONNECTIONS`` connections of ~7, some 1 700 items on 1 200 lines.

Every entry point calls it through :func:`springtrack.params.parse_toml`: the CLI's
``--model``/``--params`` files, the Python API (``model.load``/``loads``,
``params.load``/``resolve``) and the firmware's model upload.
"""
from __future__ import annotations

import re

MAX_TEXT_BYTES = 256 * 1024     # the whole text (also the link's largest model upload)
MAX_KEY_SEGMENTS = 8            # parts of one dotted key or table header: a.b.c is 3
MAX_NESTING = 8                 # arrays and inline tables inside each other
MAX_ITEMS = 4096                # keys, table headers and array elements, all together
MAX_LINES = 8192                # lines (tomllib's cost per line, even blank or a comment)
MAX_MARKS = 8 * MAX_ITEMS       # brackets, dots, commas and '=' outside strings and comments
                                # (a valid item takes at most a few: 1.5e3, [..], a.b = ...)

# the characters that change the scanner's state; everything else is skipped in one search
_SIGNIFICANT = re.compile(r"[\"'#\[\]{}=.,\n]")


class TomlBoundsError(ValueError):
    """Text beyond one of the bounds; the message names it and its limit."""


def _string_end(text: str, i: int) -> int:
    """The index after the string that starts at ``text[i]`` (a quote), or len(text) if it
    is not closed (the parser then reports it)."""
    q = text[i]
    if text.startswith(q * 3, i):                     # multi-line string
        j = i + 3
        while True:
            k = text.find(q * 3, j)
            if k < 0:
                return len(text)
            if q == '"' and _escaped(text, k):
                j = k + 1
                continue
            while text.startswith(q, k + 3):          # up to two quotes may end the content
                k += 1
            return k + 3
    end = text.find("\n", i)                         # single-line strings end at the line
    end = len(text) if end < 0 else end
    j = i + 1
    while True:
        k = text.find(q, j, end)
        if k < 0:
            return end
        if q == '"' and _escaped(text, k):
            j = k + 1
            continue
        return k + 1


def _escaped(text: str, k: int) -> bool:
    """Whether ``text[k]`` is preceded by an odd number of backslashes."""
    b = k
    while b > 0 and text[b - 1] == "\\":
        b -= 1
    return (k - b) % 2 == 1


def check(text, source: str = "<string>") -> str:
    """``text`` (str, or bytes/bytearray of UTF-8) as str, if it is within every bound;
    else :class:`TomlBoundsError` naming ``source`` and the bound.  Text that is not
    UTF-8 raises UnicodeDecodeError."""
    size = len(text) if isinstance(text, (bytes, bytearray)) else len(text.encode("utf-8", "surrogatepass"))
    if size > MAX_TEXT_BYTES:
        raise TomlBoundsError(f"{source}: {size} bytes: model and parameter text is limited "
                              f"to {MAX_TEXT_BYTES} bytes")
    if isinstance(text, (bytes, bytearray)):
        text = bytes(text).decode("utf-8")
    lines = text.count("\n") + 1
    if lines > MAX_LINES:
        raise TomlBoundsError(f"{source}: {lines} lines: model and parameter text is limited "
                              f"to {MAX_LINES} lines; not parsed")

    def refuse(what: str, limit: int, pos: int) -> None:
        line = text.count("\n", 0, pos) + 1
        raise TomlBoundsError(f"{source}: line {line}: {what} (at most {limit}); "
                              f"not parsed")

    stack: list[str] = []       # open '[' and '{' of values
    key = True                  # reading a key (else a value)
    header = False              # inside a [table] or [[array]] header
    segments = 1
    items = marks = 0
    i, n = 0, len(text)
    while True:
        m = _SIGNIFICANT.search(text, i)
        if m is None:
            break
        i = m.start()
        c = text[i]
        if c in "\"'":
            i = _string_end(text, i)
            continue
        if c == "#":
            j = text.find("\n", i)
            i = n if j < 0 else j
            continue
        i += 1
        if c == "\n":
            if not stack:
                key, header, segments = True, False, 1
            continue
        marks += 1
        if marks > MAX_MARKS:
            refuse("too many brackets, dots, commas and '=' outside strings", MAX_MARKS, i)
        if key:
            if c == ".":
                segments += 1
                if segments > MAX_KEY_SEGMENTS:
                    refuse("a dotted key or table header of too many parts",
                           MAX_KEY_SEGMENTS, i)
            elif c == "=":
                key, segments = False, 1
                items += 1
            elif c == "[" and not stack:
                if not header:
                    header = True
                    items += 1
            elif c == "]" and header:
                pass
            elif c == "}" and stack and stack[-1] == "{":   # {} : an empty inline table
                stack.pop()
                key = False
            continue
        # a value
        if c in "[{":
            stack.append(c)
            if len(stack) > MAX_NESTING:
                refuse("arrays or inline tables nested too deeply",
                       MAX_NESTING, i)
            if c == "{":
                key, segments = True, 1
        elif c in "]}":
            if stack:
                stack.pop()
        elif c == ",":
            items += 1
            if stack and stack[-1] == "{":
                key, segments = True, 1
        if items > MAX_ITEMS:
            refuse("too many keys, tables and array elements", MAX_ITEMS, i)
    if items > MAX_ITEMS:
        refuse("too many keys, tables and array elements", MAX_ITEMS, n)
    return text
