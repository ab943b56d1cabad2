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

Running and reading runs (docs/python.md): ``run(experiment, **overrides)`` runs an experiment and
returns its ``Run``; ``open_run`` opens a stored run by id, unique id prefix, 'latest' or folder (a
reference that finds none, or of the wrong type, is one ``StoreError`` line, an ``EngineBenchError``);
``Run.table()``, ``Run.jobs()`` and ``Run.predictions(method, target)`` are pandas DataFrames;
``picks_frame(run)`` is each job's selected hyperparameters and ``folds_frame(run)`` the selection
scores behind them (docs/runs.md)::

    from enginebench.api import open_run, run

    result = run("marine-diesel-egt-quick", methods=["naive-mean", "ridge"], repetitions=2)
    result.table(metrics=["mae"])             # method, target, Delta, split, metric, mean, low, high, n...
    open_run("latest").jobs()                 # one row per job: status, reason, param:<name>, time:<name>

A model a run stored (``run --keep-models``; docs/models.md) opens with ``load_model(path)``: a
``StoredModel`` whose ``simulate(u, y_init)`` or ``predict(X)`` gives what the run's job gave.
"""

from __future__ import annotations

from enginebench import declare
from enginebench.datasets.pools import RawSegments, SamplePool
from enginebench.declare import Declaration
from enginebench.errors import DataError, EngineBenchError, MethodError, SpecError, StoreError
from enginebench.method import (
    FAMILIES, Method, Params, SearchSpace, SegmentPredictions, check_log_grid_option, grid_points, log_grid, split_rows,
)
from enginebench.results.model_store import StoredModel, load_model
from enginebench.results.picks import folds_frame, picks_frame
from enginebench.runs import TABLE_COLUMNS, Run, open_run, run
from enginebench.samples import Samples, SegmentSamples
from enginebench.testing import ConformanceError, ConformanceReport, check_method, tiny_samples

__all__ = [
    "FAMILIES",
    "ConformanceError",
    "ConformanceReport",
    "DataError",
    "Declaration",
    "EngineBenchError",
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
    "SpecError",
    "StoreError",
    "StoredModel",
    "TABLE_COLUMNS",
    "check_log_grid_option",
    "check_method",
    "declare",
    "folds_frame",
    "grid_points",
    "load_model",
    "log_grid",
    "open_run",
    "picks_frame",
    "run",
    "split_rows",
    "tiny_samples",
]
