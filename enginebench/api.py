"""The public surface for method authors: everything a plugin needs, from one import.

A plugin (a ``--plugin file.py`` or a package registered under the ``enginebench.methods``
entry point group) imports from here only::

    from enginebench.api import Declaration, Method, MethodError, SegmentPredictions, declare, log_grid, split_rows

``Declaration`` and the field constructors of ``declare`` (``declare.flag``, ``declare.whole``,
``declare.log_grid``...) declare a method's options once (``Method.declared_options``).

Names here are kept stable across releases; the modules they come from (enginebench.method,
enginebench.samples, datasets.pools, testing) are internal and may move. ``check_method``
is the conformance suite for a plugin's tests; ``SamplePool``/``RawSegments``/
``tiny_samples`` build samples for tests of one's own.

Reading stored runs: ``open_run`` opens a run by id, unique id prefix, 'latest' or folder
(a ``Run``; a reference that finds none is one ``StoreError`` line), ``picks_frame(run)`` is
each job's selected hyperparameters and ``folds_frame(run)`` the selection scores behind
them (docs/runs.md)::

    from enginebench.api import folds_frame, open_run, picks_frame

    run = open_run("latest")                  # or a run id, or Path("enginebench-runs/<id>")
    picks = picks_frame(run)                  # method, target, window, split, repetition, param:<name>...
"""

from __future__ import annotations

from enginebench import declare
from enginebench.datasets.pools import RawSegments, SamplePool
from enginebench.declare import Declaration
from enginebench.errors import MethodError, StoreError
from enginebench.method import (
    FAMILIES, Method, Params, SearchSpace, SegmentPredictions, check_log_grid_option, grid_points, log_grid, split_rows,
)
from enginebench.results.picks import folds_frame, picks_frame
from enginebench.results.store import Run, open_run
from enginebench.samples import Samples, SegmentSamples
from enginebench.testing import ConformanceError, ConformanceReport, check_method, tiny_samples

__all__ = [
    "FAMILIES",
    "ConformanceError",
    "ConformanceReport",
    "Declaration",
    "Method",
    "MethodError",
    "Params",
    "RawSegments",
    "Run",
    "SamplePool",
    "Samples",
    "SearchSpace",
    "SegmentPredictions",
    "SegmentSamples",
    "StoreError",
    "check_log_grid_option",
    "check_method",
    "declare",
    "folds_frame",
    "grid_points",
    "log_grid",
    "open_run",
    "picks_frame",
    "split_rows",
    "tiny_samples",
]
