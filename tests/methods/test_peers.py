"""Peer adapters (SysIdentPy's FROLS NARX, nfoursid's N4SID): conformance, free runs from the init window,
no measured output after it, and the one-line refusal when the optional extra is absent."""

from __future__ import annotations

import importlib.util
from dataclasses import replace

import numpy as np
import pytest
import scipy.signal

from enginebench.errors import MethodError
from enginebench.methods import peers
from enginebench.methods.peers import INSTALL, N4SID, SysIdentPyNARX, initial_state, simulate_state_space
from enginebench.testing import check_method
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


@needs_nfoursid
def test_n4sid_conformance():
    check_method(N4SID, {"orders": (1, 2)})


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
def test_sysidentpy_narx_conformance():
    check_method(SysIdentPyNARX, SMALL_SYSIDENTPY)


@needs_sysidentpy
def test_bad_peer_options_are_one_line():
    with pytest.raises(MethodError, match="option degrees=.* must list degrees from 1 to 5"):
        SysIdentPyNARX(degrees=(0, 2))
    with pytest.raises(MethodError, match="option block_rows must be a whole number >= 1"):
        N4SID(block_rows=0)
