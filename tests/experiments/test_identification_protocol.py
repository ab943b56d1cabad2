"""The identification protocol (docs/protocol.md, "Identification runs in detail"): records split, init window, selection inside records, refit."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.io import write_dataset
from enginebench.datasets.schema import Column, Schema
from enginebench.datasets.splits import make_splits, parse_record_entry
from enginebench.errors import DataError, SpecError
from enginebench.experiments.runner import run_experiment
from enginebench.experiments import selection as selection_module
from enginebench.experiments.selection import LONG_BLOCK, edge_warnings, record_blocks, scored_pieces
from enginebench.experiments.spec import from_dict
from enginebench.method import Method, SegmentPredictions
from enginebench.registry import register
from enginebench.results.store import RunStore

SEEN: list[dict] = []
"""What the probe method saw, one entry per call (the tests read it back in this process)."""


@register
class Probe(Method):
    """Predicts a constant c (searched) and records what it was given."""

    name = "test-probe"
    family = "baseline"
    modes = frozenset({"simulation"})

    @classmethod
    def default_options(cls):
        return {"c_grid": (0.0, 1.0, 2.0)}

    def search_space(self, data):
        return {"c": np.array(self.options["c_grid"], dtype=float)}

    def fit(self, train, params, rng):
        SEEN.append({"call": "fit", "rows": len(train), "segments": [len(s.t) for s in train.segments]})
        return float(params["c"])

    def predict(self, fitted, data):
        SEEN.append({"call": "predict", "y_init": [None if s.y_init is None else s.y_init.shape for s in data.segments],
                     "first_row": [int(s.rows[0]) for s in data.segments],
                     "lengths": [len(s.t) for s in data.segments], "init": data.init_samples})
        return SegmentPredictions([np.full((len(s), 1), fitted) for s in data.segments])


class KeyErrorMethod(Method):
    name = "test-keyerror"
    family = "baseline"
    modes = frozenset({"simulation", "static"})

    def fit(self, train, params, rng):
        raise KeyError("missing column 'zz'")


register(KeyErrorMethod)


def records_dataset(lengths=(400, 300), dt: float = 0.01) -> Dataset:
    """Records 'est' and 'val' (time restarting at 0) of y = u filtered, plus 1 (so y is never 0)."""
    rng = np.random.default_rng(0)
    frames = []
    for name, n in zip(("est", "val"), lengths):
        u = rng.normal(size=n)
        y = np.zeros(n)
        for i in range(1, n):
            y[i] = 0.8 * y[i - 1] + 0.5 * u[i - 1]
        frames.append(pd.DataFrame({SEGMENT: name, TIME: np.arange(n) * dt, "u": u, "y": y + 1.0}))
    schema = Schema((Column("u", "input", "V"), Column("y", "output", "V")))
    return Dataset("recs", pd.concat(frames, ignore_index=True), schema, dt, {"provenance": "test"})


@pytest.fixture
def recs_file(tmp_path) -> Path:
    return write_dataset(records_dataset(), tmp_path / "recs.parquet")


def spec(dataset, **changes):
    raw = {"name": "recs-exp", "dataset": str(dataset), "targets": ["y"], "mode": "simulation", "repetitions": 1,
           "train_size": 0, "split": {"kind": "records", "train": ["est"], "test": ["val"]},
           "selection": {"kind": "none"}, "methods": {"test-probe": {}}}
    raw.update(changes)
    return from_dict(raw, origin="test")


def store_hash(root: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(root.rglob("*")) if root.exists() else []:
        h.update(str(p.relative_to(root)).encode())
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


# -- records split ---------------------------------------------------------------------------
def test_record_entries_parse_as_python_slices():
    assert parse_record_entry("SNLS80mV[40650:]") == ("SNLS80mV", 40650, None)
    assert parse_record_entry(" est [ :-50 ]") == ("est", None, -50)
    assert parse_record_entry("est") == ("est", None, None)
    with pytest.raises(SpecError, match=r"'est\[1:2:3\]' is not a record name or NAME\[start:stop\]"):
        parse_record_entry("est[1:2:3]")


def test_records_split_slices_follow_python_semantics():
    ds = records_dataset()
    (split,) = make_splits(ds, kind="records", train=["est[100:]"], validation=["est[:100]"], test=["val[-50:]"])
    assert split.train.segment_ids == ["est[100:400]"] and len(split.train) == 300
    assert split.validation.segment_ids == ["est[0:100]"] and len(split.validation) == 100
    assert split.test.segment_ids == ["val[250:300]"]
    np.testing.assert_array_equal(split.test.frame["u"].to_numpy(), ds.frame["u"].to_numpy()[400 + 250:])


@pytest.mark.parametrize("options, message", [
    ({"train": ["est"], "test": ["nope"]},
     "split records: unknown record 'nope' in test; records of dataset 'recs': est, val"),
    ({"train": ["est[:200]"], "test": ["est[150:]"]},
     "split records: 'est[150:]' (test) and 'est[:200]' (train) share samples 150..199 of record 'est'; "
     "make the slices disjoint"),
    ({"train": ["est", "est[5:9]"], "test": ["val"]},
     "split records: 'est[5:9]' (train) and 'est' (train) share samples 5..8 of record 'est'"),
    ({"train": ["est[10:11]"], "test": ["val"]},
     "split records: 'est[10:11]' (train) selects 1 sample(s) of record 'est' (400 samples); a part needs at least 2"),
])
def test_records_split_errors(options, message):
    with pytest.raises(SpecError) as err:
        make_splits(records_dataset(), kind="records", **options)
    assert str(err.value).startswith(message)


@pytest.mark.parametrize("split, message", [
    ({"kind": "records", "test": ["val"]}, "test: [split] kind = 'records' needs 'train'"),
    ({"kind": "records", "train": "est", "test": ["val"]}, "test: [split] train must be a list of record names"),
    ({"kind": "holdout", "test_fracton": 0.2}, "test: [split] kind = 'holdout': unknown key(s) test_fracton "
                                                "(did you mean 'test_fraction'?)"),
    ({"kind": "holdout", "test_fraction": True}, "test: [split] test_fraction must be a fraction in (0, 1), got True"),
])
def test_split_tables_are_checked_when_the_spec_is_read(split, message):
    with pytest.raises(SpecError) as err:
        spec("x.parquet", split=split)
    assert str(err.value).startswith(message)


def test_split_may_be_given_as_a_kind_string():
    assert spec("x.parquet", mode="static", split="holdout").split == {"kind": "holdout"}


@pytest.mark.parametrize("changes, message", [
    ({"repetitions": True}, "test: 'repetitions' must be an integer >= 1, got True"),
    ({"windows": True, "mode": "window"}, "test: 'windows' must be a list of non-negative numbers of seconds"),
    ({"init_samples": 2.5}, "test: 'init_samples' must be a whole number of samples >= 0, got 2.5"),
    ({"init_samples": 5, "mode": "static"}, "test: init_samples = 5 needs mode = 'simulation' (mode is 'static')"),
    ({"selection": {"kind": "kfold", "refit": "yes"}}, "test: selection refit must be true or false, got 'yes'"),
])
def test_booleans_are_not_numbers(changes, message):
    with pytest.raises(SpecError) as err:
        spec("x.parquet", **changes)
    assert str(err.value).startswith(message)


def test_new_keys_at_their_default_leave_the_config_hash_unchanged():
    base = spec("x.parquet")
    d = base.to_dict()
    assert "init_samples" not in d and "refit" not in d["selection"]
    assert spec("x.parquet", init_samples=0).config_hash() == base.config_hash()
    assert spec("x.parquet", init_samples=3).config_hash() != base.config_hash()


# -- the init window ------------------------------------------------------------------------
def test_a_simulating_method_sees_exactly_the_init_window_and_metrics_skip_it(recs_file, tmp_path):
    SEEN.clear()
    N = 25
    run = run_experiment(spec(recs_file, init_samples=N, methods={"test-probe": {"c_grid": [0.0]}}),
                         RunStore(tmp_path / "runs"), workers=1).run
    (pred,) = [s for s in SEEN if s["call"] == "predict"]
    assert pred["y_init"] == [(N, 1)] and pred["first_row"] == [N] and pred["lengths"] == [300] and pred["init"] == N
    (fit,) = [s for s in SEEN if s["call"] == "fit"]
    assert fit["segments"] == [400]  # training records whole, from their first sample
    y = records_dataset().frame.query("segment == 'val'")["y"].to_numpy()
    m = run.metrics()
    mae = m[(m["split"] == "test") & (m["metric"] == "mae")]["value"].item()
    assert mae == pytest.approx(np.mean(np.abs(y[N:])), rel=1e-12)  # the constant 0 scored on rows N.. only
    assert mae != pytest.approx(np.mean(np.abs(y)), rel=1e-6)


def test_init_window_longer_than_a_test_record_is_refused_before_any_job(recs_file, tmp_path):
    root = tmp_path / "runs"
    with pytest.raises(DataError, match=r"segment 'val': 300 rows, not longer than the state initialisation window "
                                        r"init_samples = 300; lower init_samples"):
        run_experiment(spec(recs_file, init_samples=300), RunStore(root), workers=1)
    assert not root.exists() or not any(root.iterdir())


# -- selection inside one record ---------------------------------------------------------------
def test_record_blocks_cut_records_into_contiguous_blocks():
    blocks = record_blocks(np.array([100]), 3, init_samples=10)
    assert [v for _, v in blocks] == [[(0, 0, 33)], [(0, 33, 67)], [(0, 67, 100)]]
    assert [f for f, _ in blocks] == [[(0, 33, 100)], [(0, 0, 33), (0, 67, 100)], [(0, 0, 67)]]
    two = record_blocks(np.array([50, 50]), 3, init_samples=5)
    assert two[1] == ([(0, 0, 33), (1, 17, 50)], [(0, 33, 50), (1, 0, 17)])  # a block spanning two records: two pieces
    with pytest.raises(SpecError, match="fold 1 of 5 has no block longer than init_samples \\+ 1 = 21 samples"):
        record_blocks(np.array([100]), 5, init_samples=20)


def test_kfold_selection_inside_one_estimation_record(recs_file, tmp_path):
    SEEN.clear()
    run = run_experiment(spec(recs_file, init_samples=10, selection={"kind": "kfold", "folds": 4}),
                         RunStore(tmp_path / "runs"), workers=1).run
    fits = [s for s in SEEN if s["call"] == "fit"]
    preds = [s for s in SEEN if s["call"] == "predict"]
    # 4 folds x 3 grid points of fits on the other blocks, then the final fit on the whole record
    assert [f["segments"] for f in fits[:3]] == [[300]] * 3 and fits[3]["segments"] == [100, 200]
    assert fits[-1]["segments"] == [400]
    blocks = [p for p in preds if p["lengths"] == [100]]
    assert len(blocks) == 4 * 3 and all(p["y_init"] == [(10, 1)] and p["first_row"] == [10] for p in blocks)
    meta = run.job_meta(next(iter(sorted(p.stem for p in run.job_files()))))
    assert meta["status"] == "ok" and meta["search"]["resamples"] == 4
    # y is about 1 everywhere: c = 1 is the best constant, and it sits inside the grid (no edge warning); a
    # constant is the training mean at best, which the job says
    assert meta["params"] == {"c": 1.0}
    assert [w for w in meta["warnings"] if "edge" in w] == []
    assert [w.split(" (")[0] for w in meta["warnings"]] == [
        "test-probe: no candidate scored better than the training mean on the selection's resamples"]


def test_long_validation_blocks_are_scored_on_sub_blocks_spread_over_them():
    # every block of the built-in experiments is at most LONG_BLOCK samples: scored whole, pieces unchanged
    short = [(0, 0, 49152), (1, 100, 100 + LONG_BLOCK)]
    assert scored_pieces(short, 50) == short
    n = 3_333_333  # a fold of a 1e7-sample record: m = ceil(log2 n) = 22 sub-blocks
    subs = scored_pieces([(0, 5, 5 + n)], init_samples=20)
    span = 20 + LONG_BLOCK // 22
    assert len(subs) == 22 and all(k == 0 and b - a == span for k, a, b in subs)
    assert subs[0][1] == 5 and subs[-1][2] == 5 + n  # from the block's start to its end
    gaps = np.diff([a for _, a, _ in subs])
    assert gaps.min() >= span and gaps.max() - gaps.min() <= 1  # evenly spread, never overlapping
    assert sum(b - a - 20 for _, a, b in subs) <= LONG_BLOCK  # scored samples: at most LONG_BLOCK a block


def test_kfold_selection_scores_long_blocks_on_sub_blocks_each_after_its_init_window(recs_file, tmp_path,
                                                                                      monkeypatch):
    monkeypatch.setattr(selection_module, "LONG_BLOCK", 64)  # blocks of 100 samples count as long here
    SEEN.clear()
    run_experiment(spec(recs_file, init_samples=10, selection={"kind": "kfold", "folds": 4}),
                   RunStore(tmp_path / "runs"), workers=1)
    fits = [s for s in SEEN if s["call"] == "fit"]
    preds = [s for s in SEEN if s["call"] == "predict"]
    assert [f["segments"] for f in fits[:3]] == [[300]] * 3 and fits[-1]["segments"] == [400]  # fits unchanged
    blocks = [p for p in preds if p["init"] == 10 and len(p["lengths"]) > 1]
    # each fold's block of 100 samples: ceil(log2 100) = 7 sub-blocks of 10 init + 64 // 7 = 9 scored samples
    assert len(blocks) == 4 * 3
    assert all(p["lengths"] == [19] * 7 and p["y_init"] == [(10, 1)] * 7 and p["first_row"] == [10] * 7
               for p in blocks)


def test_bootstrap_over_one_record_and_validation_without_a_part_are_refused_early(recs_file, tmp_path):
    root = tmp_path / "runs"
    with pytest.raises(SpecError, match="kind = 'bootstrap' resamples whole training records in simulation mode, and "
                                        "the training part has 1; use kind = 'kfold'"):
        run_experiment(spec(recs_file, selection={"kind": "bootstrap"}), RunStore(root), workers=1)
    with pytest.raises(SpecError, match="kind = 'validation' needs a validation part, and the split has none"):
        run_experiment(spec(recs_file, selection={"kind": "validation"}), RunStore(root), workers=1)
    with pytest.raises(SpecError, match="fold 1 of 40 has no block longer than init_samples \\+ 1 = 11"):
        run_experiment(spec(recs_file, init_samples=10, selection={"kind": "kfold", "folds": 40}), RunStore(root),
                       workers=1)
    assert store_hash(root) == store_hash(tmp_path / "nothing")


# -- refit ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("refit, rows", [(True, [300, 100]), (False, [300])])
def test_refit_after_validation_selection_uses_the_validation_part(recs_file, tmp_path, refit, rows):
    SEEN.clear()
    split = {"kind": "records", "train": ["est[100:]"], "validation": ["est[:100]"], "test": ["val"]}
    run = run_experiment(spec(recs_file, init_samples=5, split=split, selection={"kind": "validation", "refit": refit}),
                         RunStore(tmp_path / "runs"), workers=1).run
    fits = [s for s in SEEN if s["call"] == "fit"]
    assert fits[-1]["segments"] == rows
    val_preds = [p for p in SEEN if p["call"] == "predict" and p["lengths"] == [100]]
    assert val_preds and all(p["y_init"] == [(5, 1)] for p in val_preds)  # validation scored after its init window
    meta = run.job_meta(run.job_files()[0].stem)
    assert meta["n_train"] == sum(rows) and meta["refit_on_validation"] is refit
    # refit = false tests the model the selection scored (one fit per grid point, none after)
    assert meta["tested_selected_model"] is (not refit)
    assert len(fits) == meta["search"]["grid_size"] + (1 if refit else 0) == 3 + (1 if refit else 0)


# -- warnings and failures -------------------------------------------------------------------------
def test_a_selected_value_at_the_edge_of_its_grid_is_a_job_warning(recs_file, tmp_path):
    opts = {"test-probe": {"c_grid": [-2.0, -1.0, 0.0]}}  # y is about 1: the best constant is at the upper edge
    run = run_experiment(spec(recs_file, init_samples=10, selection={"kind": "kfold", "folds": 2}, methods=opts),
                         RunStore(tmp_path / "runs"), workers=1).run
    meta = run.job_meta(run.job_files()[0].stem)
    edge = [w for w in meta["warnings"] if "training mean" not in w]  # c = 0 is worse than the mean, also said
    assert edge == ["test-probe: c = 0 selected at the upper edge of its grid [-2 .. 0]; the optimum may "
                    "lie beyond it: widen the grid"]
    assert run.job_notes()["warnings"][("test-probe", edge[0])] == 1


def test_edge_warnings_skip_short_and_non_numeric_grids():
    space = {"a": np.array([1, 2]), "b": np.array(["x", "y", "z"], dtype=object), "c": np.array([1.0, 10.0, 100.0])}
    assert edge_warnings("m", space, {"a": 2, "b": "z", "c": 10.0}) == []
    assert edge_warnings("m", space, {"a": 2, "b": "z", "c": 1.0})[0].startswith("m: c = 1 selected at the lower edge")


def test_any_exception_from_method_code_is_a_failed_job_with_its_reason(recs_file, tmp_path):
    run = run_experiment(spec(recs_file, methods={"test-keyerror": {}}), RunStore(tmp_path / "runs"),
                         workers=1).run
    assert run.info()["status"] == "finished"
    meta = run.job_meta(run.job_files()[0].stem)
    assert meta["status"] == "failed" and meta["reason"] == "KeyError: \"missing column 'zz'\""
    assert run.job_notes()["failed"] == {("test-keyerror", "KeyError: \"missing column 'zz'\""): 1}


# -- the run command says why ------------------------------------------------------------------
def test_run_lists_failure_reasons_and_warnings_and_exits_1_when_a_method_failed_entirely(recs_file, tmp_path,
                                                                                          monkeypatch):
    from click.testing import CliRunner

    from enginebench.cli.main import cli

    monkeypatch.setenv("ENGINEBENCH_STORE", str(tmp_path / "runs"))
    exp = tmp_path / "exp.toml"
    exp.write_text(f'''name = "why"
dataset = "{recs_file}"
targets = ["y"]
mode = "simulation"
repetitions = 2
train_size = 0
init_samples = 10
[split]
kind = "records"
train = ["est"]
test = ["val"]
[selection]
kind = "kfold"
folds = 2
[methods.test-probe]
c_grid = [-2.0, -1.0, 0.0]
[methods.test-keyerror]
''')
    result = CliRunner().invoke(cli, ["run", str(exp), "-j", "1", "--quiet"])
    assert result.exit_code == 1, result.output
    out = result.output
    assert "failed (2 jobs): test-keyerror: KeyError: \"missing column 'zz'\"" in out
    # the edge pick is said once, as the run's grid-edge note (the jobs' own edge warnings are not repeated)
    assert "grid edge: test-probe: c at the upper edge of its grid (0) in 2 of 2 repetitions: widen its grid" in out
    assert "selected at the upper edge" not in out
    assert out.strip().splitlines()[-1].startswith("error: every job of test-keyerror failed (reasons above); run 2")
    # the same run without the failing method exits 0
    ok = CliRunner().invoke(cli, ["run", str(exp), "-j", "1", "--quiet", "--methods", "test-probe"])
    assert ok.exit_code == 0, ok.output


def test_a_boolean_is_not_a_grid_bound():
    from enginebench.errors import MethodError
    from enginebench.method import check_log_grid_option

    with pytest.raises(MethodError, match=r"option gamma_grid=\(-1, True, 3\) must be \(low exponent, high exponent"):
        check_log_grid_option("krls", "gamma_grid", (-1, True, 3))


@register
class Noisy(Method):
    """Predicts the training mean, and overflows numpy on the way (as a method at 1e300 would)."""

    name = "test-noisy"
    family = "baseline"
    modes = frozenset({"simulation"})

    def fit(self, train, params, rng):
        np.float64(1e308) * np.float64(10.0)  # RuntimeWarning: overflow
        return float(np.mean(train.y))

    def predict(self, fitted, data):
        return SegmentPredictions([np.full((len(s), 1), fitted) for s in data.segments])


def test_numerical_warnings_of_method_code_become_job_warnings(recs_file, tmp_path, recwarn):
    run = run_experiment(spec(recs_file, methods={"test-noisy": {}}), RunStore(tmp_path / "runs"), workers=1).run
    meta = run.job_meta(run.job_files()[0].stem)
    assert meta["status"] == "ok"
    assert meta["warnings"] == ["test-noisy: RuntimeWarning: overflow encountered in scalar multiply"]
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]  # none reached the caller


def test_a_method_worse_than_the_training_mean_is_named_under_the_table():
    from enginebench.results.tables import worse_than_baseline

    rows = [("simulation", "naive-mean", "rmse", 1.0), ("simulation", "arx", "rmse", 0.5),
            ("simulation", "sindy", "rmse", 1.5), ("simulation", "sindy", "mae", 0.1),
            ("static", "naive-mean", "mae", 2.0), ("static", "krls", "mae", 2.5), ("static", "krls", "rmse", 0.1)]
    summary = pd.DataFrame([{"dataset": "d", "target": "y", "mode": m, "window": 0.0, "split": "test", "method": me,
                             "metric": mt, "mean": v} for m, me, mt, v in rows])
    assert worse_than_baseline(summary) == [
        "worse than the training mean: sindy (rmse 1.5 vs 1; y, Delta 0 s, test): its settings do not suit these data",
        "worse than the training mean: krls (mae 2.5 vs 2; y, Delta 0 s, test): its settings do not suit these data",
    ]
    level = summary.assign(mean=summary["mean"].where(summary["method"] != "arx", 0.995))
    assert worse_than_baseline(level)[1] == (
        "no better than the training mean (within 2 %): arx (rmse 0.995 vs 1; y, Delta 0 s, test): it has learnt "
        "next to nothing here")
    assert len(worse_than_baseline(level)) == 3
    unstable = summary.assign(n_diverged=np.where(summary["method"] == "sindy", 2, 0), n_segments=3)
    assert worse_than_baseline(unstable)[0] == (
        "worse than the training mean: sindy (rmse 1.5 vs 1; y, Delta 0 s, test): its free run diverged on 2 of 3 "
        "test segments (left the training outputs' envelope; held there and scored): the model is unstable on these "
        "inputs")


def test_record_patterns_expand_to_the_records_not_named_elsewhere():
    ds = records_dataset((100, 120))
    (split,) = make_splits(ds, kind="records", train=["*"], test=["val"])
    assert split.train.segment_ids == ["est"] and split.test.segment_ids == ["val"]
    (split,) = make_splits(ds, kind="records", train=["e?t"], test=["v*"])
    assert split.train.segment_ids == ["est"] and split.test.segment_ids == ["val"]
    with pytest.raises(SpecError, match=r"pattern 'x\*' \(test\) matches no record that is not named elsewhere"):
        make_splits(ds, kind="records", train=["est"], test=["x*"])
