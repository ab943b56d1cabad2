"""The public surface for method authors: everything a plugin needs, from one import.

A plugin (a ``--plugin file.py`` or a package registered under the ``enginebench.methods``
entry point group) imports from here only::

    from enginebench.api import Declaration, Method, MethodError, SegmentPredictions, declare, log_grid, split_rows

``Declaration`` and the field constructors of ``declare`` (``declare.flag``, ``declare.whole``,
``declare.log_grid``...) declare a method's options once (``Method.declared_options``).

Names here are kept stable across releases; the modules they come from (methods.base,
datasets.samples, datasets.pools, testing) are internal and may move. ``check_method``
is the conformance suite for a plugin's tests; ``SamplePool``/``RawSegments``/
``tiny_samples`` build samples for tests of one's own.
"""

from __future__ import annotations

from enginebench import declare
from enginebench.datasets.pools import RawSegments, SamplePool
from enginebench.datasets.samples import Samples, SegmentSamples
from enginebench.declare import Declaration
from enginebench.errors import MethodError
from enginebench.methods.base import (
    FAMILIES,
    Method,
    Params,
    SearchSpace,
    SegmentPredictions,
    check_log_grid_option,
    grid_points,
    log_grid,
    split_rows,
)
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
    "SamplePool",
    "Samples",
    "SearchSpace",
    "SegmentPredictions",
    "SegmentSamples",
    "check_log_grid_option",
    "check_method",
    "declare",
    "grid_points",
    "log_grid",
    "split_rows",
    "tiny_samples",
]
