"""The selected point's validation score beside its test score (``selected_score``), and the reason it gives a
method worse than the training mean: already poor on the validation blocks, or good there and not on the test."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from enginebench.results.summary import summarize
from enginebench.results.tables import worse_than_baseline


def _metrics(rows):
    keys = {"dataset": "d", "target": "y", "mode": "simulation", "window": 0.0, "family": "f", "status": "ok"}
    return pd.DataFrame([{**keys, "method": m, "repetition": r, "split": s, "metric": k, "value": v}
                         for m, r, s, k, v in rows])


def test_the_selected_score_sits_on_the_criterions_rows_averaged_over_repetitions():
    raw = _metrics([("arx", 0, "test", "rmse", 2.0), ("arx", 1, "test", "rmse", 4.0),
                    ("arx", 0, "test", "mae", 1.0), ("arx", 1, "test", "mae", 3.0),
                    ("arx", 0, "-", "selected_rmse", 0.5), ("arx", 1, "-", "selected_rmse", 1.5),
                    ("arx", 0, "-", "time_fit_s", 9.0), ("arx", 1, "-", "time_fit_s", 9.0),
                    ("naive-mean", 0, "test", "rmse", 5.0), ("naive-mean", 1, "test", "rmse", 5.0)])
    summary = summarize(raw).set_index(["method", "metric"])
    assert summary.loc[("arx", "rmse"), "mean"] == 3.0
    assert summary.loc[("arx", "rmse"), "selected_score"] == 1.0
    assert np.isnan(summary.loc[("arx", "mae"), "selected_score"])
    assert np.isnan(summary.loc[("naive-mean", "rmse"), "selected_score"])
    assert "selected_rmse" not in summary.index.get_level_values("metric")


@pytest.mark.parametrize("chosen, reason", [
    (0.4, "its selected point scored 0.4 on the validation blocks, 1.5 here: fitted on all training data it does not "
          "carry over to these records (`enginebench table RUN --folds` lists every point's fold scores)"),
    (1.2, "its selected point scored 1.2 on the validation blocks, no better than the training mean does here: no "
          "setting searched suits these data"),
    (np.nan, "its settings do not suit these data"),
])
def test_a_method_worse_than_the_mean_is_told_apart_by_its_selection_score(chosen, reason):
    summary = pd.DataFrame([{"dataset": "d", "target": "y", "mode": "simulation", "window": 0.0, "split": "test",
                             "method": m, "metric": "rmse", "mean": v, "selected_score": s}
                            for m, v, s in (("naive-mean", 1.0, np.nan), ("poly-narx", 1.5, chosen))])
    assert worse_than_baseline(summary) == [
        f"worse than the training mean: poly-narx (rmse 1.5 vs 1; y, Delta 0 s, test): {reason}"]


def test_a_job_stores_its_selected_points_score_as_a_job_row(tmp_path):
    """End to end: the job row equals the selection's best mean score, and the summary carries it."""
    from enginebench.datasets.io import write_dataset
    from enginebench.experiments.runner import run_experiment
    from enginebench.results.store import RunStore
    from helpers import make_toy

    data = write_dataset(make_toy(), tmp_path / "toy.parquet")
    exp = {"name": "toy", "dataset": str(data), "targets": ["y"], "repetitions": 2, "seed": 7, "train_size": 150,
           "selection": {"kind": "bootstrap", "resamples": 2, "criterion": "mae"},
           "methods": {"naive-mean": {}, "ridge": {}}}
    from enginebench.experiments.spec import from_dict

    run = run_experiment(from_dict(exp, origin="test"), RunStore(tmp_path / "runs"), workers=1).run
    raw = run.metrics()
    rows = raw[(raw["method"] == "ridge") & (raw["metric"] == "selected_mae")].sort_values("repetition")
    metas = sorted((m for m in run.job_metas().values() if m["method"] == "ridge"), key=lambda m: m["repetition"])
    best = [m["search"]["best_score"] for m in metas]
    assert len(best) == 2 and rows["value"].tolist() == best
    summary = summarize(raw).set_index(["method", "metric", "split"])
    assert summary.loc[("ridge", "mae", "test"), "selected_score"] == pytest.approx(np.mean(best))
    assert not (raw["metric"] == "selected_mae")[raw["method"] == "naive-mean"].any()  # nothing selected
