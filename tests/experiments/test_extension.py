"""Model selection searches past a grid's edge, up to a declared hard bound; a failing candidate fails alone."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench.datasets.pools import make_samples
from enginebench.declare import Declaration, log_grid
from enginebench.errors import MethodError
from enginebench.experiments.extension import Axis, axes, extend
from enginebench.experiments.selection import WARNED_EDGES, select
from enginebench.experiments.spec import Selection
from enginebench.method import Method, log_grid as grid_values
from enginebench.methods.krls import KRLS


class Bowl(Method):
    """Predicts a constant offset (log10 a - log10 best)^2 + (b - 3)^2 / 10 from the training mean: the selection
    score's minimum is at a = ``best`` and b = 3, wherever the grid lies."""

    name, family, modes = "bowl", "baseline", frozenset({"static", "window"})
    declared_options = Declaration(
        log_grid("a_grid", (-2, 2, 5), "a searched", searches=("a",), bound=(1e-9, 1e9)),
    )
    best = 1e-6
    fail_on: tuple[float, float] | None = None
    """(a, y): raise when fitting that a on a training part whose first target value is not y (fold 1 leaves the
    first rows out)."""

    def search_space(self, data):
        return {"a": grid_values(*self.options["a_grid"]), "b": np.array([1, 2, 3, 4, 5])}

    def search_bounds(self, data):
        return {**super().search_bounds(data), "b": (0.0, 10.0)}

    def fit(self, train, params, rng):
        if self.fail_on is not None and np.isclose(params["a"], self.fail_on[0]) and train.y[0, 0] != self.fail_on[1]:
            raise np.linalg.LinAlgError("matrix is singular for this a")
        offset = (np.log10(params["a"]) - np.log10(self.best)) ** 2 + (params["b"] - 3) ** 2 / 10
        return float(train.y.mean()) + offset

    def predict(self, fitted, data):
        return [np.full((len(s.rows), 1), fitted) for s in data.segments]


def grid_warnings(record):
    """The record's warnings but the one that says the bowl (a constant) has no skill over the mean."""
    return [w for w in record.get("warnings", []) if "training mean" not in w]


@pytest.fixture
def train(toy):
    return make_samples(toy.select_segments(["s0", "s1"]), ["y"])


def test_extension_reaches_an_optimum_far_outside_the_grid(train):
    params, record = select(Bowl(), train, Selection(kind="kfold", folds=3), np.random.default_rng(0))
    assert params["a"] == pytest.approx(1e-6) and params["b"] == 3
    assert grid_warnings(record) == []  # the optimum is inside the extended grid: nothing to widen
    assert record["grid_edges"]["a"]["edge"] is None and record["grid_edges"]["a"]["lower"] < 1e-6
    assert record["extended"]["a"][0] == pytest.approx(1e-3)  # first one grid step (a decade) past 1e-2
    assert record["grid_size"] == 25 and record["extension_points"] > 0
    table = record["table"].frame()
    assert len(table) == 3 * (25 + record["extension_points"])  # every extended point scored on every fold


def test_extension_stops_at_the_declared_bound_and_says_so(train):
    method = Bowl()
    method.best = 1e-12  # beyond the bound 1e-9
    params, record = select(method, train, Selection(kind="kfold", folds=3), np.random.default_rng(0))
    assert params["a"] == pytest.approx(1e-9)
    assert record["grid_edges"]["a"]["bound"] == pytest.approx(1e-9)
    assert grid_warnings(record) == ["bowl: a = 1e-09 selected at its declared hard bound 1e-09 (searched [1e-09 .. 100]);"
                                  " the search does not go past the bound"]


def test_a_grid_without_a_declared_bound_keeps_the_advice_to_widen_it(train):
    class Unbounded(Bowl):
        def search_bounds(self, data):
            return {}

    params, record = select(Unbounded(), train, Selection(kind="kfold", folds=3), np.random.default_rng(0))
    assert params["a"] == pytest.approx(1e-2) and "extended" not in record
    assert grid_warnings(record) == ["bowl: a = 0.01 selected at the lower edge of its grid [0.01 .. 100]; the optimum "
                                  "may lie beyond it: widen the grid"]


def test_integer_steps_stay_whole_and_stop_at_the_bound():
    axis = Axis("lags", [2.0, 4.0, 8.0, 16.0], log=True, whole=True, low=1.0, high=50.0)
    assert axis.next_value("upper") == 32.0
    axis.pushes["upper"] += 1
    axis.insert(32.0)
    assert axis.next_value("upper") == 50.0  # 32 * 2^2 = 128, cut at the bound
    axis.insert(50.0)
    assert axis.next_value("upper") is None and axis.at_bound("upper")
    assert axis.next_value("lower") == 1.0
    linear = Axis("degree", [1.0, 2.0, 3.0], log=False, whole=True, low=1.0, high=6.0)
    assert linear.next_value("upper") == 4.0 and linear.next_value("lower") is None


def test_only_numeric_grids_of_three_values_with_a_bound_are_extended():
    space = {"a": grid_values(-2, 2, 5), "kind": np.array(["x", "y", "z"]), "b": np.array([1, 2]),
             "c": np.array([1.0, 2.0, 3.0])}
    found = axes(space, {"a": (1e-9, None), "kind": (0, 1), "b": (0, 9), "c": (None, None)})
    assert list(found) == ["a", "c"] and found["a"].log and not found["c"].log


def test_extension_goes_only_past_edges_the_rules_warn_about():
    space = {"a": np.array([1.0, 2.0, 3.0])}
    calls = []

    def evaluate(points):
        calls.append(points)
        return np.array([[p["a"]] for p in points])  # best at the lower edge

    out = extend(space, [{"a": 1.0}, {"a": 2.0}, {"a": 3.0}], np.array([[1.0], [2.0], [3.0]]), evaluate,
                 {"a": (0.0, 10.0)}, {"a": "high"}, WARNED_EDGES)
    assert calls == [] and out.added == {} and out.at_bound == {}


def test_a_candidate_raising_on_one_fold_fails_alone_and_is_reported(train):
    method = Bowl()
    method.best = 1.0
    method.fail_on = (100.0, float(train.y[0, 0]))
    params, record = select(method, train, Selection(kind="kfold", folds=3), np.random.default_rng(0))
    assert params == {"a": 1.0, "b": 3}
    notes = record["failed_candidates"]
    assert {n["resample"] for n in notes} == {1} and all(n["point"]["a"] == 100.0 for n in notes)
    assert len(notes) == 5  # a = 100 with each of the five b values, on fold 1 only
    assert notes[0]["reason"] == "LinAlgError: matrix is singular for this a"
    assert grid_warnings(record) == ["bowl: 5 candidate(s) failed on 5 resample fit(s) and were scored as failed there "
                                  "(e.g. a=100, b=1 on resample 1: LinAlgError: matrix is singular for this a)"]
    scores = record["table"].frame()
    failed = scores[(scores["param:a"] == 100.0) & (scores["resample"] == 0)]
    assert np.isinf(failed["score"]).all() and np.isfinite(scores[scores["resample"] == 1]["score"]).all()


def test_every_candidate_failing_fails_the_job_with_the_first_reason(train):
    class Broken(Bowl):
        def fit(self, train, params, rng):
            raise ValueError("cannot fit anything")

    with pytest.raises(MethodError, match=r"every grid point gave non-finite predictions \(first failure: "
                                          r"ValueError: cannot fit anything\)"):
        select(Broken(), train, Selection(kind="kfold", folds=3), np.random.default_rng(0))


def test_krls_lambda_at_the_grid_edge_is_searched_down_to_its_bound(train):
    method = KRLS(gamma_grid=(-1, 1, 3), lambda_grid=(2, 4, 3))  # a grid of absurdly large penalties
    params, record = select(method, train, Selection(kind="kfold", folds=3), np.random.default_rng(0))
    assert params["lambda"] < 100  # the extension left the grid downwards
    assert record["extended"]["lambda"][0] == pytest.approx(10.0)


def test_a_method_no_better_than_the_mean_on_the_folds_is_told_so(train):
    _, record = select(Bowl(), train, Selection(kind="kfold", folds=3), np.random.default_rng(0))
    said = [w for w in record["warnings"] if "training mean" in w]
    assert record["best_score"] >= record["mean_score"] > 0  # the bowl predicts the mean plus an offset >= 0
    assert said == [f"bowl: no candidate scored better than the training mean on the selection's resamples (best mae "
                    f"{record['best_score']:.4g} vs the mean's {record['mean_score']:.4g}): its model class or grid "
                    "does not fit these data; expect no skill over the mean"]
    _, fitted = select(KRLS(gamma_grid=(-2, 0, 3), lambda_grid=(-3, -1, 3)), train, Selection(kind="kfold", folds=3),
                       np.random.default_rng(0))
    assert fitted["best_score"] < 0.98 * fitted["mean_score"]
    assert not any("training mean" in w for w in fitted.get("warnings", []))


def test_an_input_windows_bounds_run_from_one_sample_to_the_longest_record(train):
    from enginebench.methods.boost_fir import BoostFIR
    from enginebench.methods.nfir import NFIR

    longest = max(len(s.U) for s in train.segments) * train.dt
    assert BoostFIR(horizons=[2.0, 4.0, 8.0]).search_bounds(train) == {"horizon": (train.dt, longest)}
    assert BoostFIR(horizons=[0.0, 2.0, 4.0]).search_bounds(train)["horizon"] == (0.0, longest)  # 0: no past
    nfir = NFIR(horizons=[2.0, 4.0, 8.0]).search_bounds(train)
    assert nfir == {"gamma": (1e-8, 1e6), "lambda": (1e-14, 1e8), "horizon": (train.dt, longest)}


def test_extend_false_keeps_the_grids_as_declared(train):
    params, record = select(Bowl(), train, Selection(kind="kfold", folds=3, extend=False), np.random.default_rng(0))
    assert params["a"] == pytest.approx(1e-2) and "extended" not in record and record["grid_size"] == 25
    assert grid_warnings(record)[0].startswith("bowl: a = 0.01 selected at the lower edge of its grid")


def test_the_paper_protocol_experiments_keep_their_grids():
    from enginebench.experiments.spec import load_spec

    for name in ("marine-diesel-egt", "turboshaft-wf", "turboshaft-trq", "turboshaft-trq-ideal"):
        assert load_spec(name).selection.extend is False, name
    assert load_spec("marine-diesel-egt-quick").selection.extend is True


def test_gaps_are_refined_down_to_the_grids_median_spacing_not_its_finest():
    """A data-derived grid with two close values (horizons 2.0 and 2.1 s) does not make every gap refined down to
    their 0.02-decade spacing: the median spacing (0.29 decades here) is the resolution."""
    axis = Axis("horizon", [1.0, 2.0, 2.1, 4.0, 8.0], log=True, whole=False, low=0.1, high=100.0)
    assert abs(axis.step - np.median(np.diff(np.log10([1.0, 2.0, 2.1, 4.0, 8.0])))) < 1e-12
    new = axis.refinement(4.0)  # the 4 -> 8 gap (0.30 decades) is wider than 0.29: halved once
    assert new is not None and abs(new - np.sqrt(32.0)) < 1e-9
    axis.insert(new)
    assert axis.refinement(new) is None  # 0.15-decade gaps either side: done


def test_a_linear_axis_of_lengths_is_refined_to_a_fifth_of_the_best_value_not_to_its_finest_spacing():
    """Horizons from 0 s (a linear axis: 0 is no log value) with a 0.1 s grid near zero: around a best horizon of
    2.1 s the 0.8 s gaps are halved once (1.7 and 2.5 s), then left: 0.4 s <= a fifth of 2.1 s (0.42 s), where the
    grid's median spacing (0.1 s) would have gone on to 1.9, 2.3, 2.2, 2.0 s."""
    axis = Axis("horizon", [0.1, 0.2, 0.3], log=False, whole=False, low=0.0, high=100.0)
    assert abs(axis.step - 0.1) < 1e-12
    for v in (0.0, 0.5, 1.3, 2.1, 2.9, 4.5):
        axis.insert(v)
    left = axis.refinement(2.1)
    assert left is not None and abs(left - 1.7) < 1e-9
    axis.insert(left)
    right = axis.refinement(2.1)
    assert right is not None and abs(right - 2.5) < 1e-9
    axis.insert(right)
    assert axis.refinement(2.1) is None
    # a linear axis reaching below zero keeps the grid's spacing as its resolution
    signed = Axis("offset", [-0.3, -0.2, -0.1], log=False, whole=False, low=-10.0, high=10.0)
    for v in (0.0, 1.3, 2.1, 2.9):
        signed.insert(v)
    assert abs(signed.refinement(2.1) - 1.7) < 1e-9
    signed.insert(1.7)
    assert abs(signed.refinement(2.1) - 2.5) < 1e-9
    signed.insert(2.5)
    assert signed.refinement(2.1) is not None  # 0.4 > 0.1: refined further
