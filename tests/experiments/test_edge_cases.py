"""Numerical edge cases: each ends in a finite number, a documented nan with its note, or a failed job with a reason.

Covered elsewhere and not repeated here:

* a SINDy fit that blows up is flagged ``diverged`` and held inside its envelope:
  ``tests/methods/test_sindy.py::test_unstable_fit_diverges_and_is_counted`` and
  ``::test_non_finite_step_is_flagged_and_held``;
* an unstable MoE is flagged ``diverged``: ``tests/methods/test_moe.py::test_unstable_model_is_flagged_diverged``;
* KRLS on exactly duplicated rows at lambda = 1e-4 agrees with a reference solve:
  ``tests/methods/test_krls.py::test_duplicate_rows_and_tiny_lambda_stay_finite``;
* the MAPE refusal and PPMCC nan of the metric functions: ``tests/results/test_metrics.py``.

Here the same situations are pushed further (contradictory duplicates, lambda down to
1e-14, all-equal rows) and followed through a whole run into the stored jobs and tables.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.dataset import SEGMENT, Dataset
from enginebench.datasets.io import write_dataset
from enginebench.datasets.pools import make_samples
from enginebench.errors import EngineBenchError
from enginebench.experiments.runner import run_experiment
from enginebench.experiments.spec import from_dict
from enginebench.method import Method, SegmentPredictions
from enginebench.methods.krls import KRLS
from enginebench.methods.mtl_krls import MTLKRLS
from enginebench.registry import register
from enginebench.results.metrics import compute_metrics, mape
from enginebench.results.store import RunStore
from enginebench.results.summary import summarize
from enginebench.results.tables import to_csv, to_markdown

JOB_ERRORS = (EngineBenchError, FloatingPointError, np.linalg.LinAlgError, ValueError, RuntimeError)
"""What a job turns into a 'failed' record with a reason (experiments/jobs.py)."""


def spec_for(dataset, methods, **changes):
    raw = {"name": "edge", "dataset": str(dataset), "targets": ["y"], "repetitions": 4, "seed": 3,
           "train_size": 120, "selection": {"kind": "none"}, "methods": methods}
    raw.update(changes)
    return from_dict(raw, origin="test")


# ----------------------------------------------------------------- ill-conditioned kernels
class SmoothPM:
    """A physical model of the toy data (enough of one to feed MTL-KRLS)."""

    name = "edge-pm"
    inputs = ("u1", "u2")
    outputs = ("y",)

    def calibrate(self, segments):
        return {"offset": float(np.mean(np.concatenate([s["y"] for s in segments])))}

    def simulate(self, params, segment, dt):
        return {"y": np.sin(segment["u1"]) + params["offset"]}


def shortened(ds: Dataset, n: int) -> Dataset:
    """The first ``n`` rows of every segment."""
    return ds.with_frame(ds.frame.groupby(SEGMENT, sort=False).head(n))


def duplicated(ds: Dataset, copies: int, levels: int | None = None) -> Dataset:
    """Every row repeated ``copies`` times; with ``levels``, inputs rounded to that many values
    so that equal rows carry different targets (contradictory duplicates)."""
    frame = ds.frame.loc[ds.frame.index.repeat(copies)].reset_index(drop=True)
    if levels:
        for c in ("u1", "u2"):
            lo, hi = frame[c].min(), frame[c].max()
            frame[c] = lo + np.round((frame[c] - lo) / (hi - lo) * (levels - 1)) / (levels - 1) * (hi - lo)
    return ds.with_frame(frame)


@pytest.mark.parametrize("copies, levels", [(3, None), (2, 3), (1, 1)])
@pytest.mark.parametrize("gamma", [1e-8, 1.0, 1e8])
@pytest.mark.parametrize("lam", [1e-14, 1e-10])
def test_krls_and_mtl_krls_on_singular_kernels_give_finite_predictions_or_a_reason(toy, copies, levels, gamma, lam):
    """Duplicate rows (rank-deficient kernel), all-equal rows (rank 1), tiny lambda and extreme gamma."""
    toy = shortened(toy, 40)
    train_ds = duplicated(toy.select_segments(["s0", "s1"]), copies, levels)
    if levels == 1:  # every input row equal: the kernel matrix is all ones
        train_ds = train_ds.with_frame(train_ds.frame.assign(u1=0.5, u2=-0.25))
    test_ds = toy.select_segments(["s3"])
    pm = SmoothPM()
    train = make_samples(train_ds, ["y"], physical_model=pm)
    test = make_samples(test_ds, ["y"], physical_model=pm).without_targets()
    rng = np.random.default_rng(0)
    for method, params in ((KRLS(), {"gamma": gamma, "lambda": lam}),
                           (MTLKRLS(), {"gamma": gamma, "lambda": lam, "theta": 1.0})):
        try:
            pred = np.concatenate(method.predict(method.fit(train, params, rng), test))
        except JOB_ERRORS as exc:  # a job would record this as failed, with this reason
            assert str(exc).strip(), f"{method.name}: {type(exc).__name__} without a reason"
            continue
        assert np.isfinite(pred).all(), f"{method.name} gave non-finite predictions at {params}"
        block = method.predict_grid(train, test, [params], rng)
        assert np.isfinite(block).all()


@pytest.mark.parametrize("gamma", [1e-8, 1.0, 1e8])
@pytest.mark.parametrize("lam", [1e-4, 1e-8, 1e-10])
def test_krls_on_repeated_rows_equals_the_unique_rows_with_lambda_over_the_copies(toy, gamma, lam):
    """Each row 3 times weighs it 3 times: the same fit as the unique rows with lambda / 3.

    The singular kernel is solved as the well-posed problem it is equivalent to, not
    merely kept finite (at lambda = 1e-10 the fit itself is wild: predictions near 90 for
    targets within 6-12, and both solves agree on it).
    """
    toy = shortened(toy, 40)
    train_ds = toy.select_segments(["s0", "s1"])
    test = make_samples(toy.select_segments(["s3"]), ["y"]).without_targets()
    rng = np.random.default_rng(0)
    m = KRLS()
    rep = np.concatenate(m.predict(m.fit(make_samples(duplicated(train_ds, 3), ["y"]),
                                         {"gamma": gamma, "lambda": lam}, rng), test))
    ref = np.concatenate(m.predict(m.fit(make_samples(train_ds, ["y"]), {"gamma": gamma, "lambda": lam / 3}, rng), test))
    np.testing.assert_allclose(rep, ref, rtol=0, atol=1e-4 * max(1.0, np.abs(ref).max()))


def test_a_run_on_contradictory_duplicates_with_tiny_lambda_stores_finite_metrics(toy, tmp_path):
    toy = shortened(toy, 30)
    ds = duplicated(toy.select_segments(["s0", "s1", "s2"]), 3, levels=4)
    ds = ds.with_frame(pd.concat([ds.frame, toy.select_segments(["s3"]).frame], ignore_index=True))
    path = write_dataset(ds, tmp_path / "dup.parquet")
    spec = spec_for(path, {"krls": {"gamma_grid": [-8, 8, 3], "lambda_grid": [-14, -10, 2]}},
                    selection={"kind": "bootstrap", "resamples": 2}, train_size=0, repetitions=2)
    result = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1)
    metrics = result.run.metrics()
    for key in result.run.finished_jobs():
        meta = result.run.job_meta(key)
        assert meta["status"] == "ok" or meta["reason"].strip()
    ok = metrics[(metrics["status"] == "ok") & metrics["metric"].isin(["mae", "rmse"])]
    assert np.isfinite(ok["value"]).all()
    summary = summarize(metrics)
    assert np.isfinite(summary[summary["metric"] == "mae"]["mean"]).all()


# ----------------------------------------------------------------- MAPE and PPMCC
MAPE_NOTE = ("MAPE is undefined: 30 target values are within 0.002 of zero (smallest |y| = 0.0); "
             "report MAE or RMAE instead")


def near_zero_toy(toy: Dataset) -> Dataset:
    """The toy data with a test segment whose target passes through zero every 4 samples."""
    frame = toy.frame.copy()
    test = frame[SEGMENT] == "s3"
    frame.loc[test, "y"] = np.tile([0.0, 2.0, 4.0, -2.0], int(test.sum()) // 4)
    return toy.with_frame(frame)


def test_mape_near_zero_targets_is_refused_with_the_exact_message():
    y = np.tile([0.0, 2.0, 4.0, -2.0], 30)
    with pytest.raises(EngineBenchError) as err:
        mape(y, y + 0.1)
    assert str(err.value) == MAPE_NOTE
    values, notes = compute_metrics([y], [y + 0.1], 2.0)
    assert np.isnan(values["mape"]) and notes["mape"] == MAPE_NOTE
    assert values["mae"] == pytest.approx(0.1)  # the other metrics are still reported


def test_ppmcc_of_a_constant_prediction_is_nan_with_a_note():
    y = np.linspace(1.0, 5.0, 20)
    values, notes = compute_metrics([y], [np.full(20, 3.0)], 3.0)
    assert np.isnan(values["ppmcc"])
    assert notes["ppmcc"] == "PPMCC is undefined: prediction constant; no correlation exists"
    values, notes = compute_metrics([np.full(20, 3.0)], [y], 3.0)
    assert notes["ppmcc"] == "PPMCC is undefined: target constant; no correlation exists"
    assert notes["r2"].startswith("R^2 is undefined: target constant (all 20 values equal ")


def test_undefined_metrics_reach_the_stored_job_as_nan_with_their_note_and_the_table_as_na(toy, tmp_path):
    path = write_dataset(near_zero_toy(toy), tmp_path / "zero.parquet")
    methods = {"naive-mean": {}, "krls": {"gamma_grid": [0, 0, 1], "lambda_grid": [-2, -2, 1]}}
    result = run_experiment(spec_for(path, methods, repetitions=3), RunStore(tmp_path / "runs"), workers=1)
    assert result.n_failed == 0
    meta = result.run.job_meta("y__w0__published__naive-mean__r000")
    assert meta["notes"]["test:mape"] == MAPE_NOTE
    assert meta["notes"]["test:ppmcc"] == "PPMCC is undefined: prediction constant; no correlation exists"
    metrics = result.run.metrics()
    naive = metrics[metrics["method"] == "naive-mean"]
    for metric in ("mape", "ppmcc"):
        assert naive[naive["metric"] == metric]["value"].isna().all()
    assert metrics[metrics["metric"] == "mape"]["value"].isna().all()  # no method has a MAPE here
    summary = summarize(metrics)
    assert "mape" not in set(summary["metric"])  # nothing averaged from nan
    assert set(summary[summary["metric"] == "ppmcc"]["method"]) == {"krls"}
    lines = to_markdown(summary).splitlines()
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    assert "mape [%]" not in head  # a metric undefined for every method is left out of the wide table
    row = dict(zip(head, [c.strip() for c in next(r for r in lines if "| naive-mean |" in r).strip("|").split("|")]))
    assert row["ppmcc [-]"] == "n/a" and row["mae"] != "n/a" and row["n"] == "3"


# ----------------------------------------------------------------- NaN / inf predictions
@register
class EdgeFlaky(Method):
    """Returns inf on one test segment for every second fit, finite predictions otherwise."""

    name = "edge-flaky"
    family = "data-driven"
    calls = 0

    def fit(self, train, params, rng):
        type(self).calls += 1
        return {"mean": float(train.y.mean()), "bad": type(self).calls % 2 == 0}

    def predict(self, fitted, data):
        out = [np.full((len(s), 1), fitted["mean"]) + 0.01 * s.X[:, :1] for s in data.segments]
        if fitted["bad"] and out:
            out[0] = out[0].copy()
            out[0][len(out[0]) // 2] = np.inf
        return out


@register
class EdgeAllNaN(Method):
    name = "edge-all-nan"
    family = "data-driven"

    def fit(self, train, params, rng):
        return None

    def predict(self, fitted, data):
        return [np.full((len(s), 1), np.nan) for s in data.segments]


def test_non_finite_predictions_fail_the_job_and_are_never_averaged(toy_parquet, tmp_path):
    EdgeFlaky.calls = 0
    spec = spec_for(toy_parquet, {"naive-mean": {}, "edge-flaky": {}}, repetitions=6)
    result = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1)
    run = result.run
    metas = {r: run.job_meta(f"y__w0__published__edge-flaky__r{r:03d}") for r in range(6)}
    failed = [r for r, m in metas.items() if m["status"] == "failed"]
    assert failed == [1, 3, 5] and result.n_failed == 3
    for r in failed:
        assert metas[r]["reason"] == ("FloatingPointError: edge-flaky returned non-finite predictions for 1 "
                                      "segment(s) of the test part (first: s3)")
    metrics = run.metrics()
    mine = metrics[(metrics["method"] == "edge-flaky") & (metrics["metric"] == "mae") & (metrics["split"] == "test")]
    assert sorted(mine["repetition"]) == [0, 2, 4]  # a failed job stores no metric value
    summary = summarize(metrics)
    row = summary[(summary["method"] == "edge-flaky") & (summary["metric"] == "mae")].iloc[0]
    assert row["n_repeats"] == 3 and row["n_failed"] == 3
    assert row["mean"] == pytest.approx(mine["value"].mean()) and np.isfinite(row["mean"])
    base = summary[(summary["method"] == "naive-mean") & (summary["metric"] == "mae")].iloc[0]
    assert base["n_failed"] == 0 and base["n_repeats"] == 6
    csv = pd.read_csv(__import__("io").StringIO(to_csv(summary)))
    assert set(csv[csv["method"] == "edge-flaky"]["n_failed"]) == {3}
    assert np.isfinite(csv["mean"].dropna()).all()


def test_a_method_that_always_fails_still_shows_its_failures_in_the_table(toy_parquet, tmp_path):
    spec = spec_for(toy_parquet, {"naive-mean": {}, "edge-all-nan": {}}, repetitions=2)
    result = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1)
    assert result.n_failed == 2
    summary = summarize(result.run.metrics())
    failing = summary[summary["method"] == "edge-all-nan"]
    assert set(failing["n_failed"]) == {2} and set(failing["n_repeats"]) == {0} and failing["mean"].isna().all()
    assert set(failing["metric"]) == set(summary[summary["method"] == "naive-mean"]["metric"])
    md = to_markdown(summary)
    row = next(line for line in md.splitlines() if "edge-all-nan" in line)
    assert "| 0 | 2 | n/a |" in row  # n = 0 repetitions, 2 failed, no statistics


# ----------------------------------------------------------------- diverged simulations in a run
@register
class EdgeRunaway(Method):
    """A simulator that 'leaves its envelope' on every second test segment and says so."""

    name = "edge-runaway"
    family = "data-driven"
    modes = frozenset({"simulation"})

    def fit(self, train, params, rng):
        return float(train.y.mean())

    def predict(self, fitted, data):
        arrays = [np.full((len(s), 1), fitted) for s in data.segments]
        return SegmentPredictions(arrays, [k % 2 == 1 for k in range(len(arrays))])


def test_diverged_segments_are_counted_in_the_stored_job(toy, tmp_path):
    ds = shortened(toy, 40).with_frame(shortened(toy, 40).frame, published_split={"train": ["s0", "s1"], "test": ["s2", "s3"]})
    path = write_dataset(ds, tmp_path / "sim.parquet")
    spec = spec_for(path, {"edge-runaway": {}}, mode="simulation", repetitions=1, train_size=0)
    run = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1).run
    metrics = run.metrics()
    diverged = metrics[(metrics["metric"] == "diverged") & (metrics["split"] == "test")]["value"]
    assert list(diverged) == [1.0]  # s3, the second of the two test segments


# ----------------------------------------------------------------- a target constant over one segment
def test_a_target_constant_over_one_segment_imports_and_its_undefined_metrics_are_noted(tmp_path):
    """Constancy is judged over the whole file (tests/data/malformed/constant_target refuses a file-wide
    constant); a steady segment is real data: it imports, and R^2 / PPMCC on it are nan with a note."""
    from enginebench.datasets.importer import import_table

    rows = [(t, 600 + 7 * t, 300.0 + (t % 3)) for t in range(5)] + [(t, 650 + t, 310.0) for t in range(20, 26)]
    (tmp_path / "data.csv").write_text("t,speed,T_exh\n" + "".join(f"{t},{s},{y}\n" for t, s, y in rows))
    (tmp_path / "spec.toml").write_text('name = "steady"\nfiles = ["data.csv"]\ntime = "t"\ndt = 1.0\n[columns]\n'
                                        'speed = { role = "input", unit = "rpm" }\nT_exh = { role = "output", unit = "degC" }\n')
    ds = import_table(tmp_path / "spec.toml")
    assert ds.segment_ids == ["data", "data#1"]
    steady = ds.frame[ds.frame[SEGMENT] == "data#1"]["T_exh"].to_numpy()
    assert np.all(steady == 310.0)
    values, notes = compute_metrics([steady], [steady + np.linspace(-1, 1, len(steady))], 305.0)
    assert np.isnan(values["r2"]) and np.isnan(values["ppmcc"]) and np.isfinite(values["mape"])
    assert notes["ppmcc"] == "PPMCC is undefined: target constant; no correlation exists"
    assert values["mae"] == pytest.approx(np.mean(np.abs(np.linspace(-1, 1, len(steady)))))
