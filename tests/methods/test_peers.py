"""Peer adapters (SysIdentPy's FROLS NARX, nfoursid's N4SID): conformance, free runs from the init window,
no measured output after it, and the one-line refusal when the optional extra is absent."""

from __future__ import annotations

import importlib.util
import warnings
from dataclasses import replace

import numpy as np
import pytest
import scipy.signal

from enginebench.errors import MethodError
from enginebench.methods import peers
from enginebench.methods.peers import INSTALL, N4SID, SysIdentPyNARX, initial_state, simulate_state_space
from helpers import linear_raw, sim_samples

HAVE_SYSIDENTPY = importlib.util.find_spec("sysidentpy") is not None
HAVE_NFOURSID = importlib.util.find_spec("nfoursid") is not None
needs_sysidentpy = pytest.mark.skipif(not HAVE_SYSIDENTPY, reason=f"sysidentpy is not installed ({INSTALL})")
needs_nfoursid = pytest.mark.skipif(not HAVE_NFOURSID, reason=f"nfoursid is not installed ({INSTALL})")

SMALL_SYSIDENTPY = {"degrees": (1, 2), "lags": (1, 2), "n_info_values": 8}


@pytest.fixture(scope="module")
def data():
    return sim_samples(linear_raw(3, 300)), sim_samples(linear_raw(2, 200, seed=4), init_samples=10)


# -- without the extra ------------------------------------------------------------------------
def test_an_absent_package_is_named_with_the_install_command(monkeypatch):
    monkeypatch.setattr(peers, "_missing", lambda module: f"needs the optional package {module!r}: {INSTALL}")
    for cls, package in ((SysIdentPyNARX, "sysidentpy"), (N4SID, "nfoursid")):
        assert cls.available() == f"needs the optional package {package!r}: {INSTALL}"
        with pytest.raises(MethodError, match=rf"method '{cls.name}' needs the optional package '{package}': "
                                              r'pip install "enginebench\[peers\]"'):
            cls()


def test_methods_list_marks_a_missing_peer_unavailable():
    assert peers._summary("no_such_package_for_enginebench", "text") == f"UNAVAILABLE ({INSTALL}): text"
    assert peers._summary("numpy", "text") == "text"


# -- N4SID ---------------------------------------------------------------------------------------
def test_initial_state_is_recovered_from_the_window():
    rng = np.random.default_rng(0)
    A = np.array([[0.9, 0.2], [-0.2, 0.8]])
    B, C, D = np.array([[1.0], [0.5]]), np.array([[1.0, -1.0]]), np.array([[0.1]])
    U, x0 = rng.normal(size=(50, 1)), np.array([2.0, -1.0])
    Y = simulate_state_space(A, B, C, D, x0, U)
    np.testing.assert_allclose(initial_state(A, B, C, D, U, Y[:5]), x0, atol=1e-10)
    sys = scipy.signal.dlsim((A, B, C, D, 1.0), U[:, 0], x0=x0)[1]
    np.testing.assert_allclose(Y, sys, atol=1e-12)


@needs_nfoursid
def test_n4sid_simulates_a_linear_system_from_its_init_window(data):
    train, test = data
    m = N4SID()
    fit = m.fit(train, {"order": 4}, np.random.default_rng(0))
    pred = np.concatenate(m.predict(fit, test.without_targets()))
    assert np.sqrt(np.mean((pred - test.y) ** 2)) < 0.05 * test.y.std()
    d = m.describe(fit)
    assert d["order"] == 4 and d["stable"] and len(d["poles"]) == 4


@needs_nfoursid
def test_n4sid_grid_shares_the_decomposition_and_equals_fit_predict(data):
    train, test = data
    m = N4SID()
    grid = [{"order": o} for o in m.search_space(train)["order"][:3]]
    out = m.predict_grid(train, test.without_targets(), grid, np.random.default_rng(0))
    for i, p in enumerate(grid):
        one = np.concatenate(m.predict(m.fit(train, p, np.random.default_rng(0)), test.without_targets()))
        np.testing.assert_allclose(out[i], one, rtol=0, atol=1e-9)


@needs_nfoursid
def test_an_order_the_data_cannot_carry_is_skipped_by_the_grid_and_refused_by_fit(data):
    train, test = data
    m = N4SID()
    grid = [{"order": 2}, {"order": 200}]
    out = m.predict_grid(train, test.without_targets(), grid, np.random.default_rng(0))
    assert np.isfinite(out[0]).all() and np.isnan(out[1]).all()
    with pytest.raises(MethodError, match="method 'n4sid': .*order|Hankel"):
        m.fit(train, {"order": 200}, np.random.default_rng(0))


# -- SysIdentPy ----------------------------------------------------------------------------------
@needs_sysidentpy
def test_sysidentpy_narx_simulates_a_linear_system_from_its_init_window(data):
    train, test = data
    m = SysIdentPyNARX(**SMALL_SYSIDENTPY)
    fit = m.fit(train, {"degree": 1, "lags": 2}, np.random.default_rng(0))
    pred = m.predict(fit, test.without_targets())
    assert not pred.diverged.any()
    # the records are concatenated for SysIdentPy, so a few boundary rows mix two records: close, not exact
    assert np.sqrt(np.mean((np.concatenate(pred) - test.y) ** 2)) < 0.05 * test.y.std()
    assert m.describe(fit)["targets"]["y"]["n_terms"] >= 4


@needs_sysidentpy
@needs_nfoursid
@pytest.mark.parametrize("cls, options, params", [
    (SysIdentPyNARX, SMALL_SYSIDENTPY, {"degree": 2, "lags": 2}),
    (N4SID, {}, {"order": 2}),
])
def test_only_the_init_window_is_read(data, cls, options, params):
    train, test = data
    m = cls(**options)
    fit = m.fit(train, params, np.random.default_rng(0))
    before = m.predict(fit, test)  # targets present: they must not be read
    changed = replace(test, segments=tuple(replace(s, y=s.y + 50.0) for s in test.segments))
    for a, b in zip(before, m.predict(fit, changed)):
        np.testing.assert_array_equal(a, b)
    seg = test.segments[0]
    moved = m.predict(fit, replace(test, segments=(replace(seg, y_init=seg.y_init + 1.0), *test.segments[1:])))
    assert not np.allclose(moved[0], before[0])


@needs_sysidentpy
def test_bad_peer_options_are_one_line():
    with pytest.raises(MethodError, match="option degrees=.* must list degrees from 1 to 5"):
        SysIdentPyNARX(degrees=(0, 2))
    with pytest.raises(MethodError, match="option block_rows must be a whole number >= 1"):
        N4SID(block_rows=0)


# -- the peers' grids (issue 30: search what the peers' own documentation searches) --------------
@needs_sysidentpy
def test_sysidentpy_narx_searches_degrees_1_to_3_and_lags_up_to_10_where_the_data_carry_them(data):
    train, _ = data  # 3 records of 300 samples, 2 inputs
    m = SysIdentPyNARX()
    space = m.search_space(train)
    assert list(space["degree"]) == [1, 2, 3]
    assert list(space["lags"]) == list(peers.LAG_LADDER) and max(space["lags"]) == 10
    assert m.skipped == []
    short = sim_samples(linear_raw(2, 40))  # 80 rows: a tenth is 8, so only lags 1 and 2 (3 x 2 + 1 parameters)
    space = m.search_space(short)
    assert list(space["lags"]) == [1, 2]
    assert [r.split(":")[0] for r in m.skipped] == ["lags 4 left out", "lags 6 left out", "lags 8 left out",
                                                    "lags 10 left out"]
    assert "shortest training segment (40 samples)" in m.skipped[0]


@needs_sysidentpy
@pytest.mark.parametrize("criterion", ["aic", "bic"])
def test_the_information_criterion_read_off_one_regression_equals_sysidentpys_own(data, criterion):
    from sysidentpy.basis_function import Polynomial
    from sysidentpy.model_structure_selection import FROLS
    from sysidentpy.parameter_estimation import LeastSquares

    train, _ = data
    U = np.vstack([s.U for s in train.segments])
    y = np.vstack([s.y for s in train.segments])
    U, y = (U - U.mean(0)) / U.std(0), (y - y.mean()) / y.std()
    y = y + 0.05 * np.random.default_rng(1).normal(size=y.shape)  # noisy, so the criterion has a minimum inside

    def frols():
        return FROLS(order_selection=True, n_info_values=12, ylag=3, xlag=[[1, 2, 3]] * 2, info_criteria=criterion,
                     estimator=LeastSquares(), basis_function=Polynomial(degree=2), model_type="NARMAX")

    stock, fast = frols(), frols()
    fast.information_criterion = peers.types.MethodType(peers._prefix_information_criterion, fast)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        stock.fit(X=U, y=y)
        fast.fit(X=U, y=y)
    np.testing.assert_allclose(fast.info_values, stock.info_values, rtol=1e-10)
    assert fast.n_terms == stock.n_terms
    np.testing.assert_array_equal(fast.final_model, stock.final_model)
    np.testing.assert_allclose(fast.theta, stock.theta, rtol=1e-9, atol=1e-12)


@needs_sysidentpy
def test_a_point_over_max_candidates_is_skipped_by_the_grid_noted_and_refused_by_fit(data):
    train, test = data  # 2 inputs: degree 2, lags 2 give C(8, 2) = 28 candidates, degree 1 lags 2 give 7
    assert peers.candidate_terms(2, 2, 2) == 28 and peers.candidate_terms(1, 2, 2) == 7
    assert peers.candidate_terms(3, 10, 1) == 1771  # Silverbox (one input) at the widest default point
    m = SysIdentPyNARX(max_candidates=20, n_info_values=8)
    m.search_space(train)
    grid = [{"degree": 1, "lags": 2}, {"degree": 2, "lags": 2}]
    out = m.predict_grid(train, test.without_targets(), grid, np.random.default_rng(0))
    assert np.isfinite(out[0]).all() and np.isnan(out[1]).all()
    reason = "degree 2, lags 2 give 28 candidate terms, over max_candidates = 20; raise max_candidates or use lower " \
             "degrees or lags"
    assert m.skipped == [reason]
    fit = m.fit(train, grid[0], np.random.default_rng(0))
    assert m.describe(fit)["skipped"] == [reason]
    with pytest.raises(MethodError, match=r"^method 'sysidentpy-narx': degree 2, lags 2 give 28 candidate terms"):
        m.fit(train, grid[1], np.random.default_rng(0))


@needs_nfoursid
def test_n4sid_searches_orders_up_to_32_where_the_data_carry_them_and_notes_the_others(data):
    train, _ = data  # 900 samples, 2 inputs, 1 output: order 32 takes 48 block rows, 4 x 48 x 3 = 576 samples
    m = N4SID()
    space = m.search_space(train)
    assert list(space["order"]) == list(peers.ORDER_LADDER) and max(space["order"]) == 32
    assert m.skipped == []
    short = sim_samples(linear_raw(1, 300))  # order 16 needs 4 x 24 x 3 = 288 samples, 24 needs 432
    space = m.search_space(short)
    assert max(space["order"]) == 16 and 24 not in space["order"]
    assert m.skipped == [
        "order 24 left out: 300 training samples are too few for the 36 Hankel block rows of order 24 (needs 432); "
        "use lower orders",
        "order 32 left out: 300 training samples are too few for the 48 Hankel block rows of order 32 (needs 576); "
        "use lower orders"]
    fit = m.fit(short, {"order": 2}, np.random.default_rng(0))
    assert m.describe(fit)["skipped"] == m.skipped


@needs_nfoursid
def test_a_failed_n4sid_decomposition_skips_that_order_with_its_reason(data, monkeypatch):
    from nfoursid.nfoursid import NFourSID

    train, test = data
    real = NFourSID.system_identification

    def fails_at_3(self, rank, *args, **kwargs):
        if rank == 3:
            raise np.linalg.LinAlgError("SVD did not converge")
        return real(self, rank, *args, **kwargs)

    monkeypatch.setattr(NFourSID, "system_identification", fails_at_3)
    m = N4SID()
    m.search_space(train)
    grid = [{"order": 2}, {"order": 3}, {"order": 4}]
    out = m.predict_grid(train, test.without_targets(), grid, np.random.default_rng(0))
    assert np.isfinite(out[[0, 2]]).all() and np.isnan(out[1]).all()
    assert m.skipped == ["nfoursid could not identify order 3: SVD did not converge; use lower orders"]


@needs_nfoursid
def test_an_infeasible_n4sid_order_is_skipped_without_failing_the_job(tmp_path):
    import pandas as pd

    from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
    from enginebench.datasets.io import write_dataset
    from enginebench.datasets.schema import Column, Schema
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict
    from enginebench.results.store import RunStore

    rng = np.random.default_rng(0)
    frames = []
    for name, n in (("est", 400), ("val", 300)):
        u = rng.normal(size=n)
        y = scipy.signal.lfilter([0.0, 0.5], [1.0, -0.8], u) + 1.0
        frames.append(pd.DataFrame({SEGMENT: name, TIME: np.arange(n) * 0.01, "u": u, "y": y}))
    ds = Dataset("recs", pd.concat(frames, ignore_index=True),
                 Schema((Column("u", "input", "V"), Column("y", "output", "V"))), 0.01, {"provenance": "test"})
    path = write_dataset(ds, tmp_path / "recs.parquet")
    spec = from_dict({"name": "n4sid-skip", "dataset": str(path), "targets": ["y"], "mode": "simulation",
                      "repetitions": 1, "train_size": 0, "init_samples": 10,
                      "split": {"kind": "records", "train": ["est"], "test": ["val"]},
                      "selection": {"kind": "kfold", "folds": 2, "criterion": "rmse"},
                      "methods": {"n4sid": {"orders": [2, 40]}}}, origin="test")
    run = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1).run
    meta = run.job_meta(run.job_files()[0].stem)
    assert meta["status"] == "ok" and int(meta["params"]["order"]) == 2
    assert any("too few for the 60 Hankel block rows of order 40" in r for r in meta["describe"]["skipped"])


@needs_sysidentpy
def test_a_criterion_still_falling_at_n_info_values_is_a_job_warning(data):
    train, _ = data
    m = SysIdentPyNARX(n_info_values=2)  # noise-free data: every further term lowers the criterion
    fit = m.fit(train, {"degree": 1, "lags": 2}, np.random.default_rng(0))
    d = m.describe(fit)
    assert d["targets"]["y"]["n_terms"] == 2 and len(d["targets"]["y"]["info_values"]) == 2
    assert d["warnings"] == ["the information criterion (aic) kept falling up to n_info_values = 2 terms (y); "
                             "raise n_info_values"]
    roomy = SysIdentPyNARX(n_info_values=7)  # all 7 candidates (1 + 3 signals x 2 lags): the criterion rises at 6
    d = roomy.describe(roomy.fit(train, {"degree": 1, "lags": 2}, np.random.default_rng(0)))
    assert d["targets"]["y"]["n_terms"] < 7 and "warnings" not in d


def _long_memory_records(tmp_path, taps: int):
    """An estimation and a validation record of a FIR response shaped as a half sine over ``taps`` samples: no
    low-order ARX compresses it, so fewer lags than ``taps`` leave part of the response out."""
    import pandas as pd

    from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
    from enginebench.datasets.io import write_dataset
    from enginebench.datasets.schema import Column, Schema

    rng = np.random.default_rng(3)
    frames = []
    for name, n in (("est", 1200), ("val", 600)):
        u = rng.normal(size=n)
        h = np.sin(np.pi * np.arange(1, taps + 1) / (taps + 1))
        y = scipy.signal.lfilter(np.r_[0.0, h], [1.0], u) + 0.01 * rng.normal(size=n)
        frames.append(pd.DataFrame({SEGMENT: name, TIME: np.arange(n) * 0.01, "u": u, "y": y}))
    ds = Dataset("long-memory", pd.concat(frames, ignore_index=True),
                 Schema((Column("u", "input", "V"), Column("y", "output", "V"))), 0.01, {"provenance": "test"})
    return write_dataset(ds, tmp_path / "long-memory.parquet")


@needs_sysidentpy
def test_sysidentpy_narx_lags_best_at_the_ladders_top_are_searched_further(tmp_path):
    """Issue 30: a peer's grid is extended like the built-in methods' (a response 16 samples long needs lags >= 16,
    past the ladder's 10), so its run ends at the lags the data ask for, not with "widen the grid"."""
    from enginebench.experiments.runner import run_experiment
    from enginebench.experiments.spec import from_dict
    from enginebench.results.store import RunStore

    path = _long_memory_records(tmp_path, 16)
    train = sim_samples(linear_raw(1, 1200))  # one record of 1,200 samples and 2 inputs: a quarter is 300
    assert SysIdentPyNARX().search_bounds(train) == {"lags": (1.0, float(peers.LAG_BOUND)), "degree": (1.0, 3.0)}
    assert SysIdentPyNARX(degrees=[2, 4]).search_bounds(train)["degree"] == (1.0, 4.0)  # never below the grid
    spec = from_dict({"name": "peer-extension", "dataset": str(path), "targets": ["y"], "mode": "simulation",
                      "repetitions": 1, "train_size": 0, "init_samples": 20,
                      "split": {"kind": "records", "train": ["est"], "test": ["val"]},
                      "selection": {"kind": "kfold", "folds": 2, "criterion": "rmse"},
                      "methods": {"sysidentpy-narx": {"degrees": [1]}}}, origin="test")
    run = run_experiment(spec, RunStore(tmp_path / "runs"), workers=1).run
    meta = run.job_meta(run.job_files()[0].stem)
    assert meta["status"] == "ok"
    assert int(meta["params"]["lags"]) >= 16, meta["params"]
    assert not any("widen" in w for w in meta.get("warnings", [])), meta.get("warnings")


@needs_nfoursid
def test_n4sid_bound_is_the_highest_order_the_data_carry():
    """The extension's bound for n4sid's order: the highest order whose Hankel matrices the samples fill, within
    ORDER_BOUND (900 samples, 2 inputs, 1 output: 75 block rows need 4 x 75 x 3 = 900; order 50 has 75)."""
    assert N4SID().search_bounds(sim_samples(linear_raw(3, 300))) == {"order": (1.0, 50.0)}
    assert N4SID().search_bounds(sim_samples(linear_raw(1, 5000))) == {"order": (1.0, float(peers.ORDER_BOUND))}
    assert N4SID(block_rows=4).search_bounds(sim_samples(linear_raw(1, 5000))) == {"order": (1.0, 4.0)}
