"""The one renderer of terminal tables and notes: every table the command line prints goes through ``grid``
(a rich table without borders, fitted to the terminal), every list of notes through ``note_text``.

``grid`` wraps the widest cells (at spaces, so a list written "a, b, c" wraps between its names) instead of
cutting them, so a table fits ``width`` columns (the terminal's, 80 when unknown or not a terminal) and keeps
every name whole; a column marked ``no_wrap`` (ids, numbers) is never wrapped. ``note_text`` says each note
once, wrapped to the width with a hanging indent.
"""

from __future__ import annotations

import io
import shutil
import textwrap
from typing import Any, Iterable, Sequence


def term_width(width: int | None = None) -> int:
    """``width`` when given, else the terminal's columns ($COLUMNS first), 80 when not known."""
    return int(width) if width else shutil.get_terminal_size((80, 24)).columns


def _sized() -> bool:
    """Whether output has a width to fit: a terminal, or $COLUMNS set."""
    import os
    import sys

    return bool(os.environ.get("COLUMNS")) or sys.stdout.isatty()


def render(*renderables: Any, width: int | None = None) -> str:
    """Rich renderables as plain text ``width`` columns wide (no colour, no trailing spaces), newline-terminated."""
    from rich.console import Console

    out = io.StringIO()
    console = Console(file=out, width=term_width(width), color_system=None, force_terminal=False,
                      highlight=False, emoji=False, markup=False, soft_wrap=False)
    for r in renderables:
        console.print(r)
    return "".join(line.rstrip() + "\n" for line in out.getvalue().splitlines())


def grid(header: Sequence[str], rows: Iterable[Sequence[Any]], *, right: Sequence[bool] | None = None,
         no_wrap: Sequence[bool] | None = None, max_width: Sequence[int | None] | None = None, width: int | None = None, title: str | None = None,
         rule: bool = True, indent: int = 0) -> str:
    """A table: ``header`` then ``rows`` (cells as text; None as ""), columns two spaces apart, a rule under the
    header when ``rule``, fitted to ``width`` (see the module). ``right`` marks right-aligned columns (numbers),
    ``no_wrap`` columns never wrapped, ``max_width`` caps columns (None: no cap; both only where the table is
    fitted: without ``width``, output that is neither a terminal nor sized by $COLUMNS gets whole rows); ``title`` is a line above, ``indent`` spaces before every line."""
    from rich import box
    from rich.table import Table

    n = len(header)
    right = list(right) if right is not None else [False] * n
    keep = list(no_wrap) if no_wrap is not None else [False] * n
    caps = list(max_width) if max_width is not None else [None] * n
    wide = width is None and not _sized()  # a pipe or a file: whole rows, for grep and logs
    if wide:
        caps = [None] * n
    table = Table(box=box.SIMPLE_HEAD if rule else None, show_edge=False, pad_edge=False, padding=(0, 1, 0, 0),
                  show_header=True, header_style=None, expand=False)
    for h, r, k, cap in zip(header, right, keep, caps):
        table.add_column(str(h), justify="right" if r else "left", no_wrap=k, overflow="fold", max_width=cap)
    for row in rows:
        table.add_row(*["" if c is None else str(c) for c in row])
    text = render(table, width=10_000 if wide else term_width(width) - indent)
    lines = [line for line in text.splitlines() if line.strip() or not rule]
    if rule:  # rich's SIMPLE_HEAD draws its rule in box characters: a dashed line reads the same in any log
        lines = [line.replace("─", "-") for line in lines]
    pad = " " * indent
    out = "".join(pad + line + "\n" for line in lines)
    return (pad + title + "\n" if title else "") + out


def unique(lines: Iterable[str]) -> list[str]:
    """``lines`` without repeats (the first of each kept, in order; whitespace differences do not count)."""
    seen, out = set(), []
    for line in lines:
        key = " ".join(str(line).split())
        if key not in seen:
            seen.add(key)
            out.append(str(line))
    return out


def note_text(lines: Iterable[str], width: int | None = None, indent: str = "", hang: str = "    ") -> str:
    """Each note once, wrapped to ``width`` (``indent`` and the note's own leading spaces before its first line,
    ``hang`` more before the rest); words and paths are never broken. '' for no notes. Without ``width``, output
    that is neither a terminal nor sized by $COLUMNS (a pipe, a file) keeps each note on one whole line."""
    if width is None and not _sized():  # a pipe or a file: each note one whole line, for grep and logs
        return "".join(indent + line.rstrip() + "\n" for line in unique(lines))
    w = term_width(width)

    def fill(line: str) -> str:
        lead = indent + line[:len(line) - len(line.lstrip(" "))]  # a note's own indent (a nested line) is kept
        return textwrap.fill(" ".join(line.split()), w, initial_indent=lead, subsequent_indent=lead + hang,
                             break_long_words=False, break_on_hyphens=False)

    return "".join(fill(line) + "\n" for line in unique(lines))
