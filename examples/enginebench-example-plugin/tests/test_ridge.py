"""The example method passes enginebench's conformance suite."""

from enginebench.api import check_method

from enginebench_example import Ridge


def test_ridge_conforms():
    report = check_method(Ridge, {"alpha_grid": (-2, 2, 5)})
    assert "determinism[static]" in report.passed
