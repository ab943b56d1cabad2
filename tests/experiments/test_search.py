"""Search beyond grids: ranges read from a search space, random and Bayesian (optuna) search, the [selection] keys."""

from __future__ import annotations

import importlib.util
import json
import sys
from importlib import resources

import numpy as np
import pytest

from enginebench.datasets.dataset import Dataset
from enginebench.datasets.pools import make_samples
from enginebench.errors import SpecError
from enginebench.experiments.search import (BAYES_BATCH, Range, check_search, infer_range, random_points, ranges,
                                            search_points)
from enginebench.experiments.selection import select
from enginebench.experiments.spec import Selection, from_dict, load_spec
from enginebench.method import Method, grid_points
from helpers import make_toy, toy_spec

HAS_OPTUNA = importlib.util.find_spec("optuna") is not None
needs_optuna = pytest.mark.skipif(not HAS_OPTUNA, reason="optuna is not installed (pip install enginebench[search])")
SEARCHES = ["random", pytest.param("bayes", marks=needs_optuna)]


# ----------------------------------------------------------------------------- ranges from a search space
def test_log_spaced_numbers_are_a_log_uniform_range():
    assert infer_range("gamma", np.logspace(-4, 4, 41)) == Range("gamma", "float", 1e-4, 1e4, log=True)


def test_evenly_spaced_floats_are_a_uniform_range():
    assert infer_range("b", np.linspace(0.0, 1.0, 11)) == Range("b", "float", 0.0, 1.0)


def test_integers_are_an_integer_range_log_scaled_when_log_spaced():
    assert infer_range("n", np.array([2, 3, 4])) == Range("n", "int", 2, 4)
    assert infer_range("n", np.array([4, 2, 3, 3])) == Range("n", "int", 2, 4)  # order and repeats do not matter
    assert infer_range("n", np.array([1, 10, 100])) == Range("n", "int", 1, 100, log=True)
    assert infer_range("n", np.array([1, 2, 7, 9])) == Range("n", "int", 1, 9)  # irregular integers: still a range


def test_everything_else_is_a_choice_among_the_given_values():
    assert infer_range("s", np.array(["a", "b", "c"], dtype=object)) == Range("s", "choice", choices=("a", "b", "c"))
    assert infer_range("f", np.array([True, False, True])) == Range("f", "choice", choices=(True, False))
    assert infer_range("lr", np.array([1e-3, 1e-2])) == Range("lr", "choice", choices=(1e-3, 1e-2))  # < 3 values
    assert infer_range("x", np.array([0.1, 0.2, 0.7])) == Range("x", "choice", choices=(0.1, 0.2, 0.7))  # irregular
    assert infer_range("x", np.array([1.0, np.inf, 3.0])).kind == "choice"
    assert infer_range("e", np.array([100])) == Range("e", "choice", choices=(100,))
    kinds = {name: r.kind for name, r in ranges({"a": np.logspace(0, 2, 3), "s": np.array(["x", "y"])}).items()}
    assert kinds == {"a": "float", "s": "choice"}


def test_random_points_lie_in_their_ranges_with_their_types():
    space = {"a": Range("a", "float", 1e-3, 1e3, log=True), "b": Range("b", "float", -1.0, 1.0),
             "n": Range("n", "int", 2, 40, log=True), "m": Range("m", "int", 1, 3),
             "s": Range("s", "choice", choices=("x", "y"))}
    points = random_points(space, 400, np.random.default_rng(0))
    a, b = np.array([p["a"] for p in points]), np.array([p["b"] for p in points])
    n, m = np.array([p["n"] for p in points]), np.array([p["m"] for p in points])
    assert len(points) == 400 and all(isinstance(p["n"], int) and isinstance(p["a"], float) for p in points)
    assert a.min() >= 1e-3 and a.max() <= 1e3 and b.min() >= -1 and b.max() <= 1
    assert set(n) <= set(range(2, 41)) and set(m) == {1, 2, 3} and {p["s"] for p in points} == {"x", "y"}
    # log-uniform: about half the draws below the geometric middle (1 and sqrt(80))
    assert 0.4 < np.mean(a < 1.0) < 0.6 and 0.4 < np.mean(n < np.sqrt(1.5 * 40.5)) < 0.6
    assert 0.4 < np.mean(b < 0.0) < 0.6


def test_random_points_of_a_discrete_space_are_kept_once():
    space = {"n": Range("n", "int", 2, 4), "s": Range("s", "choice", choices=("x", "y"))}
    points = random_points(space, 50, np.random.default_rng(1))
    assert len(points) == 6 and len({tuple(p.values()) for p in points}) == 6


# ----------------------------------------------------------------------------- a toy objective with a known optimum
A_OPT, B_OPT = 1.3, 0.4


class ToyObjective(Method):
    """Scores (log10 a - 1.3)^2 + (b - 0.4)^2 on data whose target is 10 everywhere: the MAE of a prediction of
    10 + that value is exactly that value, so the optimum is a = 10^1.3, b = 0.4."""

    name = "toy-objective"

    def __init__(self, a_range: tuple[float, float] = (-1, 3)) -> None:
        super().__init__()
        self.a_range = a_range
        self.calls: list[int] = []

    def search_space(self, data):
        return {"a": np.logspace(*self.a_range, 9), "b": np.linspace(0.0, 1.0, 11)}

    def predict_grid(self, train, data, grid, rng):
        self.calls.append(len(grid))
        value = np.array([(np.log10(p["a"]) - A_OPT) ** 2 + (p["b"] - B_OPT) ** 2 for p in grid])
        return np.broadcast_to(10.0 + value[:, None, None], (len(grid), len(data), 1)).copy()


@pytest.fixture(scope="module")
def flat():
    """Two segments whose target is 10 on every row."""
    ds = make_toy(n_segments=2, n=40)
    return make_samples(Dataset("flat", ds.frame.assign(y=10.0), ds.schema, ds.dt, ds.meta), ["y"])


def _pick(flat, search: str, seed: int, trials: int = 60, **kw):
    method = ToyObjective(**kw)
    params, record = select(method, flat, Selection(search=search, trials=trials, resamples=2),
                            np.random.default_rng(seed))
    return method, params, record


@pytest.mark.parametrize("search", SEARCHES)
def test_search_is_deterministic_under_a_seed(flat, search):
    _, p1, r1 = _pick(flat, search, 3, trials=20)
    _, p2, r2 = _pick(flat, search, 3, trials=20)
    _, _, r3 = _pick(flat, search, 4, trials=20)
    assert r1["table"].grid == r2["table"].grid and p1 == p2 and r1["table"].chosen == r2["table"].chosen
    np.testing.assert_array_equal(r1["table"].scores, r2["table"].scores)
    assert r1["table"].grid != r3["table"].grid
    assert r1["search"] == search and r1["grid_size"] == len(r1["table"].grid)


@needs_optuna
def test_optuna_says_nothing_that_would_become_a_job_warning(flat):
    import warnings

    import optuna

    with warnings.catch_warnings(record=True) as caught:  # as a job catches them (jobs.caught_warnings)
        warnings.simplefilter("always")
        _pick(flat, "bayes", 0, trials=20)
    assert [str(w.message) for w in caught] == []
    assert optuna.logging.get_verbosity() == optuna.logging.WARNING  # no "Trial N finished" line per trial


@needs_optuna
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bayes_finds_the_optimum_of_the_toy_objective(flat, seed):
    _, params, record = _pick(flat, "bayes", seed)
    assert abs(np.log10(params["a"]) - A_OPT) < 0.15 and abs(params["b"] - B_OPT) < 0.15
    assert record["best_score"] < 0.02  # the 9 x 11 grid's best is (1.5 - 1.3)^2 = 0.04
    assert record["best_score"] == pytest.approx((np.log10(params["a"]) - A_OPT) ** 2 + (params["b"] - B_OPT) ** 2)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_finds_the_optimum_of_the_toy_objective_more_loosely(flat, seed):
    _, params, record = _pick(flat, "random", seed)
    assert abs(np.log10(params["a"]) - A_OPT) < 0.35 and abs(params["b"] - B_OPT) < 0.35
    assert record["best_score"] < 0.15


@needs_optuna
def test_random_asks_for_every_point_at_once_and_bayes_in_batches(flat):
    method, _, record = _pick(flat, "random", 0, trials=20)
    assert method.calls == [20, 20]  # one predict_grid call per resample
    method, _, record = _pick(flat, "bayes", 0, trials=20)
    assert BAYES_BATCH == 8 and method.calls == [8, 8, 8, 8, 4, 4]  # each batch: one call per resample
    assert len(record["table"].grid) == 20 and record["table"].scores.shape == (20, 2)


class DiscreteObjective(ToyObjective):
    """A 3 x 2 discrete space scored (n - 3)^2 + [s == "y"]."""

    def search_space(self, data):
        return {"n": np.array([2, 3, 4]), "s": np.array(["x", "y"], dtype=object)}

    def predict_grid(self, train, data, grid, rng):
        self.calls.append(len(grid))
        value = np.array([(p["n"] - 3) ** 2 + (p["s"] == "y") for p in grid], dtype=float)
        return np.broadcast_to(10.0 + value[:, None, None], (len(grid), len(data), 1)).copy()


@pytest.mark.parametrize("search", SEARCHES)
def test_a_point_proposed_twice_is_scored_once(flat, search):
    method = DiscreteObjective()
    params, record = select(method, flat, Selection(search=search, trials=30, resamples=2), np.random.default_rng(0))
    grid = record["table"].grid
    assert len({tuple(p.values()) for p in grid}) == len(grid) <= 6 and sum(method.calls) == 2 * len(grid)
    assert params == {"n": 3, "s": "x"} and record["best_score"] == 0.0


@needs_optuna
def test_the_table_lists_the_trials_in_order_with_their_scores(flat):
    _, params, record = _pick(flat, "bayes", 5, trials=12)
    table = record["table"]
    expected = [(np.log10(p["a"]) - A_OPT) ** 2 + (p["b"] - B_OPT) ** 2 for p in table.grid]
    np.testing.assert_allclose(table.scores, np.repeat(np.array(expected)[:, None], 2, axis=1), rtol=1e-12)
    assert table.grid[table.chosen] == params and table.chosen == int(np.argmin(expected))
    frame = table.frame()
    assert list(frame["point"].unique()) == list(range(12))
    np.testing.assert_allclose(frame.loc[frame["resample"] == 0, "param:a"], [p["a"] for p in table.grid])


@needs_optuna
def test_a_pick_near_a_range_end_is_a_warning_and_an_edge(flat):
    # a spans 10^-1 .. 10^1: the optimum 10^1.3 lies beyond the upper end
    _, params, record = _pick(flat, "bayes", 0, a_range=(-1, 1))
    assert np.log10(params["a"]) > 0.96
    edge = record["grid_edges"]["a"]
    assert edge["edge"] == "upper" and edge["warn"] and edge["upper"] == pytest.approx(10.0)
    assert record["grid_edges"]["b"]["edge"] is None
    assert [w for w in record["warnings"] if "toy-objective: a = " in w and "upper end of its range" in w]


def test_grid_search_is_the_default_and_tries_the_product_grid(flat):
    method = ToyObjective()
    params, record = select(method, flat, Selection(resamples=2), np.random.default_rng(0))
    assert record["table"].grid == grid_points(method.search_space(flat)) and "search" not in record
    assert params == {"a": pytest.approx(10 ** 1.5), "b": pytest.approx(0.4)}
    assert method.calls == [99, 99]


def test_search_points_refuses_an_unknown_search():
    with pytest.raises(ValueError, match="search 'grid' is not one of random, bayes"):
        search_points({"a": np.arange(3)}, "grid", 5, np.random.default_rng(0), lambda points: np.zeros((0, 1)))


# ----------------------------------------------------------------------------- the [selection] keys
def _spec(**selection):
    return from_dict({"dataset": "x.parquet", "targets": ["y"], "methods": ["krls"], "selection": selection})


def test_selection_search_and_trials_are_declared_and_checked():
    assert _spec().selection.search == "grid" and _spec().selection.trials == 50
    assert _spec(search="bayes", trials=7).selection == Selection(search="bayes", trials=7)
    with pytest.raises(SpecError, match=r"^spec: selection search 'baye' is not one of grid, random, bayes "
                                        r"\(did you mean 'bayes'\?\)$"):
        _spec(search="baye")
    with pytest.raises(SpecError, match=r"^spec: selection trials must be a whole number >= 1, got 0$"):
        _spec(trials=0)
    with pytest.raises(SpecError, match="selection trials must be a whole number >= 1, got True"):
        _spec(trials=True)
    with pytest.raises(SpecError, match=r"unknown key\(s\) trails \(did you mean 'trials'\?\)"):
        _spec(trails=5)


def test_the_config_hash_is_unchanged_at_the_defaults():
    base = _spec()
    assert _spec(search="grid", trials=50).config_hash() == base.config_hash()
    assert "search" not in base.to_dict()["selection"] and "trials" not in base.to_dict()["selection"]
    assert _spec(search="random").config_hash() != base.config_hash()
    assert _spec(trials=49).config_hash() != base.config_hash()
    assert _spec(search="random", trials=9).with_overrides(seed=1).selection == Selection(search="random", trials=9)
    for name in ("gas-turbine-nox-quick", "marine-diesel-egt-quick"):  # every published baseline's hash
        doc = json.loads((resources.files("enginebench.results") / "published" / f"{name}.json").read_text())
        assert load_spec(name).config_hash() == doc["config_hash"]


def test_bayes_without_optuna_is_refused_before_the_first_job(monkeypatch, tmp_path, toy_parquet):
    from enginebench.experiments.runner import run_experiment
    from enginebench.results.store import RunStore

    monkeypatch.setitem(sys.modules, "optuna", None)  # import optuna -> ImportError
    check_search("random")
    message = (r"^\[selection\] search = 'bayes' needs optuna, which is not installed; "
               r"pip install enginebench\[search\]$")
    with pytest.raises(SpecError, match=message):
        check_search("bayes")
    store = RunStore(tmp_path / "runs")
    with pytest.raises(SpecError, match=message):
        run_experiment(toy_spec(toy_parquet, selection={"resamples": 2, "search": "bayes"}), store, workers=1)
    assert not list((tmp_path / "runs").glob("*/jobs/*"))


# ----------------------------------------------------------------------------- end to end
@needs_optuna
def test_a_bayes_run_stores_its_trials_in_the_selection_table(tmp_path, toy_parquet):
    from enginebench.experiments.runner import run_experiment
    from enginebench.results.store import RunStore

    spec = toy_spec(toy_parquet, repetitions=2, selection={"resamples": 2, "search": "bayes", "trials": 10})
    run = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1).run
    table = run.selection_table()
    krls = table[table["method"] == "krls"]
    assert set(krls["repetition"]) == {0, 1}
    for rep, rows in krls.groupby("repetition"):
        assert sorted(rows["point"].unique()) == list(range(10)) and len(rows) == 20
        gamma = rows["param:gamma"]
        assert gamma.between(1e-2, 1.0).all() and gamma.nunique() == 10  # drawn from the range, not the 3-point grid
        chosen = rows[rows["chosen"]]
        mean = rows.groupby("point")["score"].mean()
        assert chosen["point"].nunique() == 1 and chosen["point"].iloc[0] == mean.idxmin()


# ----------------------------------------------------------------------------- moe's searched hyperparameters
def test_moe_default_search_space_is_the_one_it_always_searched():
    from enginebench.methods.moe import MoE

    old = {"n_experts": np.array([2, 3, 4]), "beta1": np.array([1.0]), "beta2": np.array([0.1, 1.0]),
           "k": np.array([1.0]), "gate_hidden": np.array([16]), "lr": np.array([1e-3, 1e-2]), "epochs": np.array([100])}
    space = MoE().search_space(None)
    assert list(space) == list(old)
    for name, values in old.items():
        assert space[name].dtype == values.dtype and np.array_equal(space[name], values), name
    assert {f.name: f.searches for f in MoE.declared_options if f.searches} == {
        "experts_grid": ("n_experts",), "beta1_grid": ("beta1",), "beta2_grid": ("beta2",), "k_grid": ("k",),
        "gate_hidden_grid": ("gate_hidden",), "lr_grid": ("lr",), "epochs_grid": ("epochs",)}


def test_moe_searched_hyperparameters_are_options_with_ranges():
    from enginebench.errors import MethodError
    from enginebench.methods.moe import MoE

    space = MoE(experts_grid=[2, 4, 8], lr_grid=[1e-4, 1e-3, 1e-2], epochs_grid=[50, 100, 150]).search_space(None)
    found = ranges(space)
    assert found["n_experts"] == Range("n_experts", "int", 2, 8, log=True)
    assert found["lr"] == Range("lr", "float", 1e-4, 1e-2, log=True)
    assert found["epochs"] == Range("epochs", "int", 50, 150)
    assert found["beta2"] == Range("beta2", "choice", choices=(0.1, 1.0))
    with pytest.raises(MethodError, match=r"^method 'moe': option experts_grid=\[0, 2\] must be a non-empty list of "
                                          r"whole numbers >= 1"):
        MoE(experts_grid=[0, 2])
    with pytest.raises(MethodError, match=r"option lr_grid=\[\] must be a non-empty list of numbers > 0"):
        MoE(lr_grid=[])


def test_moe_default_epochs_follow_the_record_length():
    """epochs_grid = None: 100 epochs where they give 2,000 gradient steps (10,240 rows of 512), more below; a given
    grid is kept as given."""
    from enginebench.methods.moe import MoE
    from enginebench.methods.moe.options import default_epochs, search_space

    assert default_epochs(1024, 512) == 1000 and default_epochs(10240, 512) == 100 and default_epochs(10, 512) == 2000
    assert default_epochs(10241, 512) == 100 and default_epochs(5000, 512) == 200
    options = MoE().options
    assert search_space(options, 1024)["epochs"].tolist() == [1000]
    assert search_space({**options, "epochs_grid": [50, 100]}, 1024)["epochs"].tolist() == [50, 100]
    assert search_space(options)["epochs"].tolist() == [100]
