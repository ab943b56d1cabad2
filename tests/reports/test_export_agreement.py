"""The export checks' agreement: largest absolute and relative difference on the rows the run scored; a NaN output
never agrees."""

from __future__ import annotations

import numpy as np

from enginebench.reports.fmu_export import Agreement


def test_agreement_reads_the_scored_rows_and_scales_by_each_outputs_largest_magnitude():
    seg = {"rows": np.array([1, 2]), "prediction": np.array([[10.0, 0.5, 9.0], [20.0, -1.0, 9.0]])}
    Y = np.array([[999.0, 999.0], [10.5, 0.5], [20.0, -0.9]])  # row 0 is the init window: not compared
    a = Agreement()
    a.add(Y, seg, [0, 1])
    assert a.steps == 2 and a.max_abs == 0.5
    assert abs(a.max_rel - 0.1) < 1e-12  # 0.1 / 1.0 on the second output beats 0.5 / 20 on the first


def test_a_nan_output_counts_as_no_agreement():
    seg = {"rows": np.array([0]), "prediction": np.array([[1.0]])}
    a = Agreement()
    a.add(np.array([[np.nan]]), seg, [0])
    assert a.max_abs == np.inf and a.max_rel == np.inf
