"""Evaluated records whose inputs leave the training range are named once under every view of a run (the
F-16's level-4 force: a model that is fine on level 2 diverges there)."""

from __future__ import annotations

import numpy as np
import pandas as pd

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.io import write_dataset
from enginebench.datasets.pools import RawSegments, SegmentArrays
from enginebench.datasets.schema import Column, Schema
from enginebench.experiments.coverage import range_coverage
from enginebench.results.notes import coverage_note_lines


def _raw(*segments: tuple[str, np.ndarray]) -> RawSegments:
    segs = tuple(SegmentArrays(id=sid, U=U, Y=np.zeros((len(U), 1)), t=np.arange(len(U), dtype=float), Z=None)
                 for sid, U in segments)
    return RawSegments(segments=segs, inputs=("a", "b"), outputs=("y",), internals=(), dt=1.0, units={}, dataset="d")


def test_a_record_is_named_where_enough_rows_lie_past_the_margin():
    ramp = np.linspace(0.0, 1.0, 1001)
    train = _raw(("t0", np.column_stack([ramp, ramp])), ("t1", np.column_stack([ramp[::-1], 2 * ramp])))
    inside = np.column_stack([ramp, ramp])  # a: [0, 1], b: [0, 2] in training
    past = inside.copy()
    past[:100, 0] = 1.2  # 10 % of the rows 0.2 spans past a's maximum
    spike = inside.copy()
    spike[:5, 0] = 3.0  # 0.5 % of the rows: under MIN_FRACTION
    grazing = inside.copy()
    grazing[:, 1] = 2.08  # every row, 0.04 spans of b past its maximum: inside the 5 % margin
    coverage = range_coverage({"s": {"train": train, "test": _raw(("in", inside), ("past", past), ("spike", spike),
                                                                   ("grazing", grazing))}})
    assert coverage["records"] == {"test": 4}
    [entry] = coverage["outside"]
    assert entry == {"split": "s", "part": "test", "segment": "past", "column": "a", "role": "input", "fraction": 100 / 1001,
                     "reach": entry["reach"], "low": 0.0, "high": 1.0}
    assert np.isclose(entry["reach"], 0.2)


def test_the_note_names_the_record_most_outside():
    info = {"range_coverage": {"records": {"test": 2}, "outside": [
        {"split": "s", "part": "test", "segment": "L4", "column": "Force", "role": "input", "fraction": 0.31, "reach": 0.42,
         "low": -5.2, "high": 5.1}]}}
    assert coverage_note_lines(info) == [
        "inputs beyond the training range: Force in 1 of 2 test records (most: L4, 31 % of its rows outside the "
        "training's [-5.2, 5.1], reaching 0.42 of that span past it): a model fitted on the training records "
        "extrapolates there"]
    assert coverage_note_lines({}) == []  # runs made before the record was kept


def _amplitude_run(tmp_path):
    """A run trained on a unit-amplitude record and tested on one at 0.8 and one at three times that amplitude."""
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict
    from enginebench.results.store import RunStore

    rng = np.random.default_rng(0)
    frames = []
    for name, scale in (("est", 1.0), ("low", 0.8), ("high", 3.0)):
        u = np.clip(rng.normal(size=400), -2.5, 2.5) * scale
        frames.append(pd.DataFrame({SEGMENT: name, TIME: np.arange(400.0), "u": u, "y": 0.5 * u}))
    ds = Dataset("amp", pd.concat(frames, ignore_index=True),
                 Schema((Column("u", "input", "N"), Column("y", "output", "m"))), 1.0, {"provenance": "test"})
    path = write_dataset(ds, tmp_path / "amp.parquet")
    spec = from_dict({"name": "cov", "dataset": str(path), "targets": ["y"], "mode": "simulation", "repetitions": 1,
                      "train_size": 0, "init_samples": 5, "split": {"kind": "records", "train": ["est"],
                                                                     "test": ["low", "high"]},
                      "selection": {"kind": "none"}, "methods": {"naive-mean": {}}}, origin="test")
    return run_experiment(spec, RunStore(tmp_path / "runs"), workers=1).run


def test_a_run_says_which_test_record_extrapolates(tmp_path):
    from enginebench.results.notes import run_note_lines

    run = _amplitude_run(tmp_path)
    [line] = [x for x in run_note_lines(run) if x.startswith("inputs beyond")]
    assert line.startswith("inputs beyond the training range: u in 1 of 2 test records (most: high, ")
    assert "of its rows outside the training's [-2.5, 2.5], reaching 1 of that span past it)" in line  # 7.5 - 2.5 = 5
    [line] = [x for x in run_note_lines(run) if x.startswith("outputs beyond")]  # y = u / 2: the output too
    assert line.startswith("outputs beyond the training range: y in 1 of 2 test records (most: high, ")
    assert "outside the training's [-1.25, 1.25], reaching 1 of that span past it)" in line


def test_table_runs_show_and_the_reports_carry_the_note(tmp_path):
    """Every view of the run says it once: `table`, `runs show`, index.html and report.html."""
    import html

    from click.testing import CliRunner

    from enginebench.cli.main import cli

    run = _amplitude_run(tmp_path)
    store = str(tmp_path / "runs")
    runner = CliRunner()
    start = "inputs beyond the training range: u in 1 of 2 test records (most: high, "
    for args in (["table", run.id], ["runs", "show", run.id]):
        out = runner.invoke(cli, [*args, "--store", store])
        assert out.exit_code == 0, out.output
        assert sum(start in x for x in out.output.splitlines()) == 1, out.output
    out = runner.invoke(cli, ["report", run.id, "--store", store, "-o", str(tmp_path / "rep")])
    assert out.exit_code == 0, out.output
    for page in ("index.html", "report.html"):
        text = html.unescape((tmp_path / "rep" / page).read_text())
        assert start in text, page
