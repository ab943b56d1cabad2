"""The formats of ``enginebench table --format``: each name with the function that renders it, the one place to add one.

A renderer is named as ``"module:function"`` so that listing the formats (the CLI's ``--format`` choices) imports
nothing heavy; it is called as ``render(summary, metrics, title=..., units=..., width=...)`` (a run's summary frame,
the metric columns asked for, the run id, ``{column: unit}`` and the terminal width; a format ignores what it has no
use for) and returns the text that ``table`` prints or writes.
"""

from __future__ import annotations

from importlib import import_module
from typing import Callable

RENDERERS: dict[str, str] = {
    "term": "enginebench.results.tables:to_term",
    "md": "enginebench.results.tables:to_markdown",
    "latex": "enginebench.results.tables:to_latex",
    "csv": "enginebench.results.tables:to_csv",
    "html": "enginebench.results.tables:to_html",
}
FORMATS = tuple(RENDERERS)


def renderer(fmt: str) -> Callable[..., str]:
    """The function rendering format ``fmt`` (one of :data:`FORMATS`)."""
    module, name = RENDERERS[fmt].split(":")
    return getattr(import_module(module), name)
