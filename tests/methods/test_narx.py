"""Kernel NARX: the batched free run against a plain per-step reference, recovery of a known nonlinear
system's free run, no measured output read after the init window, grid batching, divergence flags, the
kernel's regressors clipped to the training range."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.dataset import Dataset
from enginebench.datasets.pools import RawSegments, SamplePool
from enginebench.datasets.schema import Schema
from enginebench.errors import MethodError
from enginebench.method import SegmentPredictions, grid_points
from enginebench.methods.freerun import Envelope
from enginebench.methods.narx import NARX
from enginebench.methods.narx_model import NARXFit
from enginebench.samples import Samples

PARAMS = {"lags": 2, "nk": 0, "gamma": 0.3, "lambda": 1e-6}


def system(u: np.ndarray) -> np.ndarray:
    """y(t) = 0.5 y(t-1) - 0.2 y(t-2) - 0.1 y(t-1)^2 + tanh(u(t-1)) + 0.1 u(t-2)^2, from rest."""
    y = np.zeros(len(u))
    for t in range(2, len(u)):
        y[t] = 0.5 * y[t - 1] - 0.2 * y[t - 2] - 0.1 * y[t - 1] ** 2 + np.tanh(u[t - 1]) + 0.1 * u[t - 2] ** 2
    return y


def nonlinear_raw(n_seg: int = 4, n: int = 300, seed: int = 0, lengths: tuple[int, ...] | None = None,
                  amplitude: float = 1.5) -> RawSegments:
    """Records of ``system`` driven by uniform noise in +-``amplitude``."""
    rng = np.random.default_rng(seed)
    frames = []
    for k, size in enumerate(lengths or (n,) * n_seg):
        u = rng.uniform(-amplitude, amplitude, size)
        frames.append(pd.DataFrame({"segment": f"s{k}", "time": np.arange(size) + 1000.0 * k, "u": u,
                                    "y": system(u) + 1.0}))
    ds = Dataset("nl", pd.concat(frames, ignore_index=True), Schema.from_roles({"u": "input", "y": "output"}), 1.0)
    return RawSegments.from_dataset(ds)


def samples(raw: RawSegments, init_samples: int = 0) -> Samples:
    return SamplePool(raw, ["y"], "simulation", init_samples=init_samples).materialize()


@pytest.fixture(scope="module")
def data() -> tuple[Samples, Samples]:
    return samples(nonlinear_raw(3, 200, seed=0)), samples(nonlinear_raw(2, 300, seed=1), init_samples=5)


@pytest.fixture(scope="module")
def fitted(data) -> NARXFit:
    return NARX().fit(data[0], PARAMS, np.random.default_rng(0))


def reference_run(fit: NARXFit, U: np.ndarray, window: np.ndarray) -> np.ndarray:
    """The free run written out step by step: standardise, build z(t) (edge padded, clipped to the kernel box),
    linear part + kernel sum."""
    m, box = fit.models[0], fit.kernel_box()
    ys = list((window[:, 0] - fit.y_mean[0]) / fit.y_std[0])
    us = (U[:, 0] - fit.u_mean[0]) / fit.u_std[0]
    for t in range(len(window), len(U)):  # the kernel reads its regressors clipped to the training range
        z = np.r_[[np.clip(ys[max(t - i, 0)], box.y_lo[0], box.y_hi[0]) for i in range(m.ka, 0, -1)],
                  [np.clip(us[max(t - m.nk - l, 0)], box.u_lo[0], box.u_hi[0]) for l in range(m.kb)]]
        lin = sum(m.a[i - 1] * ys[max(t - i, 0)] for i in range(1, m.na + 1)) + m.c0 \
            + sum(m.b[0, l] * us[max(t - m.nk - l, 0)] for l in range(m.nb))
        ys.append(lin + float(np.exp(-m.gamma / m.d * ((m.centres - z) ** 2).sum(axis=1)) @ m.beta))
    return np.array(ys) * fit.y_std[0] + fit.y_mean[0]


def test_free_run_equals_the_step_by_step_reference(data, fitted):
    _, test = data
    pred = NARX().predict(fitted, test.without_targets())
    assert isinstance(pred, SegmentPredictions) and not pred.diverged.any()
    for seg, p in zip(test.segments, pred):
        ref = reference_run(fitted, seg.U, seg.y_init)
        np.testing.assert_allclose(p[:, 0], ref[5:], rtol=0, atol=1e-10)


def test_nystroem_free_run_equals_the_reference_too(data):
    train, test = data
    m = NARX(exact_max_rows=100, centres=60, nk=1, na=3, nb=2)
    fit = m.fit(train, {"na": 3, "nb": 2, "nk": 1, "gamma": 0.5, "lambda": 1e-4}, np.random.default_rng(3))
    assert fit.solver == "nystroem" and fit.models[0].centres.shape == (60, 5)
    seg = test.segments[1]
    pred = m.predict(fit, test.without_targets())[1][:, 0]
    np.testing.assert_allclose(pred, reference_run(fit, seg.U, seg.y_init)[5:], rtol=0, atol=1e-10)


def test_a_long_linear_part_beside_a_short_kernel_equals_the_reference(data):
    train, test = data
    m = NARX(kernel_lags=2)
    fit = m.fit(train, {"lags": 6, "nk": 0, "gamma": 0.3, "lambda": 1e-6}, np.random.default_rng(0))
    mod = fit.models[0]
    assert (mod.na, mod.nb, mod.ka, mod.kb, mod.d) == (6, 6, 2, 2, 4) and np.any(mod.a)
    seg = test.segments[0]
    pred = m.predict(fit, test.without_targets())[0][:, 0]
    np.testing.assert_allclose(pred, reference_run(fit, seg.U, seg.y_init)[5:], rtol=0, atol=1e-10)


def test_without_the_linear_part_the_kernel_fits_alone(data):
    train, test = data
    fit = NARX(linear=False).fit(train, PARAMS, np.random.default_rng(0))
    mod = fit.models[0]
    assert not mod.a.any() and not mod.b.any() and mod.c0 == 0.0
    seg = test.segments[1]
    pred = NARX(linear=False).predict(fit, test.without_targets())[1][:, 0]
    np.testing.assert_allclose(pred, reference_run(fit, seg.U, seg.y_init)[5:], rtol=0, atol=1e-10)


def test_window_shorter_than_the_lags_is_padded_with_y0(fitted):
    test = samples(nonlinear_raw(1, 120, seed=2))  # no init window: y0 only, two output lags
    seg = test.segments[0]
    pred = NARX().predict(fitted, test.without_targets())[0][:, 0]
    assert pred[0] == seg.y0[0]
    np.testing.assert_allclose(pred, reference_run(fitted, seg.U, seg.y0[None, :]), rtol=0, atol=1e-10)


def test_recovers_the_free_run_of_a_known_nonlinear_system(data, fitted):
    """Trained one step ahead on 600 noise-free rows; the free run on new inputs stays within 10 % of the std."""
    _, test = data
    pred = np.concatenate(NARX().predict(fitted, test.without_targets()))
    rmse = np.sqrt(np.mean((pred - test.y) ** 2))
    assert rmse < 0.1 * test.y.std()


def test_never_reads_a_measured_output_after_the_init_window(data, fitted):
    _, test = data
    before = NARX().predict(fitted, test)  # targets present: they must not be read
    changed = replace(test, segments=tuple(replace(s, y=s.y + np.random.default_rng(1).normal(50, 10, s.y.shape))
                                           for s in test.segments))
    after = NARX().predict(fitted, changed)
    for a, b in zip(before, after):
        np.testing.assert_array_equal(a, b)
    seg = test.segments[0]
    moved = replace(test, segments=(replace(seg, y_init=seg.y_init + 0.5), *test.segments[1:]))
    moved_pred = NARX().predict(fitted, moved)
    assert not np.allclose(moved_pred[0], before[0])
    np.testing.assert_array_equal(moved_pred[1], before[1])


def test_segments_of_different_lengths_batch_like_one_at_a_time(fitted):
    test = samples(nonlinear_raw(lengths=(80, 200, 130), seed=4), init_samples=3).without_targets()
    together = NARX().predict(fitted, test)
    for k, seg in enumerate(test.segments):
        alone = NARX().predict(fitted, replace(test, segments=(seg,)))
        np.testing.assert_allclose(together[k], alone[0], rtol=0, atol=1e-10)


def test_predict_grid_batches_the_candidates_like_fit_then_predict(data):
    train, test = samples(nonlinear_raw(2, 100, seed=5)), data[1]  # small: eight exact fits
    m = NARX()
    grid = grid_points({"lags": np.array([1, 2]), "nk": np.array([0]), "gamma": np.array([0.1, 1.0]),
                        "lambda": np.array([1e-5, 1e-2])})
    out = m.predict_grid(train, test.without_targets(), grid, np.random.default_rng(0))
    assert out.shape == (len(grid), len(test), 1)
    for i, p in enumerate(grid):
        one = np.concatenate(m.predict(m.fit(train, p, np.random.default_rng(0)), test.without_targets()))
        np.testing.assert_allclose(out[i], one, rtol=0, atol=1e-9)


def test_a_run_leaving_the_envelope_is_held_and_flagged(data, fitted):
    _, test = data
    view = test.without_targets()
    free = NARX().predict(fitted, view)
    tight = replace(fitted, envelope=Envelope(np.array([0.9]), np.array([1.1])))
    pred = NARX().predict(tight, view)
    assert pred.diverged.all() and not free.diverged.any()
    for p, f, seg in zip(pred, free, view.segments):
        first = int(np.argmax((f[:, 0] < 0.9) | (f[:, 0] > 1.1)))
        np.testing.assert_array_equal(p[:first], f[:first])
        held = f[first - 1, 0] if first else seg.y_init[-1, 0]  # the last value inside (or the window's last)
        assert (p[first:, 0] == held).all()


def test_grid_is_derived_from_the_data(data):
    train, _ = data
    space = NARX().search_space(train)
    assert space["lags"].tolist() == [2, 4, 8, 16]  # 200-row segments: lag <= 50, 2 lag + 1 <= 60 regressors
    assert space["nk"].tolist() == [0] and len(space["gamma"]) == 4 and len(space["lambda"]) == 5
    short = NARX().search_space(samples(nonlinear_raw(2, 40)))
    assert short["lags"].tolist() == [2]  # lag <= 10 and 2 lag + 1 <= 8 regressors
    fixed = NARX(na=3, nb=[1, 2]).search_space(train)
    assert "lags" not in fixed and fixed["na"].tolist() == [3] and fixed["nb"].tolist() == [1, 2]


@pytest.mark.parametrize("options, fragment", [
    ({"na": 0}, "option na=0 must be >= 1"),
    ({"nb": [0, 2]}, r"option nb=\[0, 2\] must be >= 1"),
    ({"gamma_grid": (1, 0)}, "option gamma_grid=.* must be"),
    ({"centres": 0}, "option centres must be a whole number >= 1"),
])
def test_bad_options_are_one_line(options, fragment):
    with pytest.raises(MethodError, match=fragment):
        NARX(**options)


def test_bad_hyperparameters_and_inputs_are_one_line(data, fitted):
    train, test = data
    with pytest.raises(MethodError, match="hyperparameter na must be a whole number >= 1"):
        NARX().fit(train, {**PARAMS, "lags": 0}, np.random.default_rng(0))
    with pytest.raises(MethodError, match="unknown hyperparameter"):
        NARX().fit(train, {**PARAMS, "alpha": 1}, np.random.default_rng(0))
    wide = replace(test, segments=tuple(replace(s, U=np.hstack([s.U, s.U]), X=np.hstack([s.X, s.X]))
                                        for s in test.segments))
    with pytest.raises(MethodError, match="has 2 feature columns but the model was fitted on 1 inputs"):
        NARX().predict(fitted, wide.without_targets())


def test_describe_names_the_model(fitted):
    d = NARX().describe(fitted)
    assert (d["na"], d["nb"], d["nk"], d["regressors"], d["solver"]) == (2, 2, 0, 4, "exact")
    assert d["gamma"] == pytest.approx(0.3 / 4) and d["lambda"] == pytest.approx(1e-6 * d["regression_rows"])


def test_nystroem_with_every_row_as_a_centre_is_exact_krls():
    from enginebench.methods.numerics.kernels import gaussian, sq_distances
    from enginebench.methods.narx_model import nystroem_ridge

    rng = np.random.default_rng(0)
    Z, y = rng.normal(size=(60, 3)), rng.normal(size=60)
    lambdas = np.array([1e-3, 1e-1])
    betas, thetas, rank = nystroem_ridge(Z, y, Z, 0.5, lambdas, block_rows=7)
    K = gaussian(sq_distances(Z), 0.5)
    assert rank == 60 and thetas is None
    for beta, lam in zip(betas, lambdas):
        np.testing.assert_allclose(beta, np.linalg.solve(K + lam * np.eye(60), y), rtol=1e-6, atol=1e-8)
    # with an unpenalised linear part: the semi-parametric system [[K + lam I, Phi], [Phi^T, 0]] [beta; theta] = [y; 0]
    Phi = np.hstack([Z, np.ones((60, 1))])
    betas, thetas, _ = nystroem_ridge(Z, y, Z, 0.5, lambdas, Phi, block_rows=7)
    for beta, theta, lam in zip(betas, thetas, lambdas):
        block = np.block([[K + lam * np.eye(60), Phi], [Phi.T, np.zeros((4, 4))]])
        ref = np.linalg.solve(block, np.r_[y, np.zeros(4)])
        np.testing.assert_allclose(beta, ref[:60], rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(theta, ref[60:], rtol=1e-6, atol=1e-7)


def test_selection_skips_lags_the_fitting_pieces_cannot_carry():
    train, test = samples(nonlinear_raw(2, 10)), samples(nonlinear_raw(1, 40, seed=2), 3)
    grid = [{"lags": 12, "nk": 0, "gamma": 0.1, "lambda": 1e-4}, {"lags": 2, "nk": 0, "gamma": 0.1, "lambda": 1e-4}]
    out = NARX().predict_grid(train, test.without_targets(), grid, np.random.default_rng(0))
    assert np.isnan(out[0]).all() and np.isfinite(out[1]).all()


def test_models_that_leave_their_limits_are_retired_without_changing_any_run_up_to_the_clip():
    """free_run with limits: a diverging model stops being simulated once it is out on every segment; every
    model's rows up to its first row out of the limits equal the run without limits, bit for bit."""
    from enginebench.methods.narx_model import KernelModel, free_run

    rng = np.random.default_rng(3)
    c, ka, kb = 1, 2, 2

    def model(a0: float, target: int = 0) -> KernelModel:
        centres = rng.normal(size=(7, ka + c * kb))
        return KernelModel(na=3, nb=2, nk=0, ka=ka, kb=kb, a=np.array([a0, 0.1, 0.0]), b=np.array([[0.3, -0.2]]),
                           c0=0.01, centres=centres, beta=rng.normal(size=7) * 0.1, gamma=0.5, lam=1e-6,
                           target=target)

    models = [model(1.3), model(0.5), model(1.6), model(0.2), model(1.2)]  # 0, 2 and 4 diverge
    lengths = [400, 250, 330]
    U = [rng.normal(size=(n, c)) for n in lengths]
    W = [rng.normal(size=(5, 1)) for _ in lengths]
    limits = np.tile([-50.0, 50.0], (len(models), 1))
    full = free_run(models, U, W, lengths)
    retired = free_run(models, U, W, lengths, limits)
    diverged = 0
    for g in range(len(models)):
        for s, n in enumerate(lengths):
            run = full[g, s, 5:n]
            out = np.flatnonzero(~((run >= -50.0) & (run <= 50.0)))
            stop = 5 + (out[0] + 1 if out.size else n - 5)
            diverged += bool(out.size)
            np.testing.assert_array_equal(retired[g, s, :stop], full[g, s, :stop])
    assert diverged == 9  # three models on three segments: the retirement was exercised


def test_models_sharing_centres_run_as_with_centres_of_their_own():
    """free_run computes one input product per draw of centres and scales it per model: the grid's candidates
    (gammas, lambdas, lags on two draws), some retired past their limits, run as the same models each holding a
    copy of its centres (one product each) to 1e-12."""
    from dataclasses import replace

    from enginebench.methods.narx_model import KernelModel, free_run

    rng = np.random.default_rng(5)
    c = 2
    models = []
    for ka, kb in ((2, 2), (3, 1)):
        centres = rng.normal(size=(9, ka + c * kb))
        for gamma, a0 in ((0.1, 0.4), (1.0, 1.7), (3.0, 0.2), (0.5, 1.4)):  # a0 > 1 diverges: retired
            models.append(KernelModel(na=3, nb=2, nk=1, ka=ka, kb=kb, a=np.array([a0, 0.1, 0.0]),
                                      b=rng.normal(size=(c, 2)) * 0.3, c0=0.01, centres=centres,
                                      beta=rng.normal(size=9) * 0.2, gamma=gamma, lam=1e-6, target=0))
    own = [replace(m, centres=m.centres.copy()) for m in models]
    lengths = [300, 180]
    U = [rng.normal(size=(n, c)) for n in lengths]
    W = [rng.normal(size=(5, 1)) for _ in lengths]
    limits = np.tile([-30.0, 30.0], (len(models), 1))
    for lim in (None, limits):
        shared, alone = free_run(models, U, W, lengths, lim), free_run(own, U, W, lengths, lim)
        for g in range(len(models)):
            for s_, n in enumerate(lengths):
                run = alone[g, s_, :n]
                out = np.flatnonzero(~(np.abs(run) <= 30.0))
                stop = n if lim is None or not out.size else out[0] + 1
                np.testing.assert_allclose(shared[g, s_, :stop], run[:stop], rtol=1e-12, atol=1e-12)
    assert sum(np.any(~(np.abs(alone[g, :, :180]) <= 30.0)) for g in range(len(models))) >= 2  # retirement ran


def test_the_linear_basis_solves_like_gelsd_with_full_rank_and_without():
    """LinearBasis: back substitution on a full-rank Phi and the minimum-norm gelsd on a rank-deficient one give
    LAPACK gelsd's least-squares solution; the projection leaves nothing in Phi's span."""
    import scipy.linalg

    from enginebench.methods.narx_model import LinearBasis

    rng = np.random.default_rng(5)
    Phi = rng.normal(size=(60, 4)) * [1.0, 1e3, 1e-2, 1.0]
    B = rng.normal(size=(60, 3))
    for P in (Phi, np.hstack([Phi, Phi[:, :1]])):  # the second has a repeated column: rank 4 of 5
        basis = LinearBasis(P)
        want = scipy.linalg.lstsq(P, B, lapack_driver="gelsd")[0]
        np.testing.assert_allclose(basis.solve(B), want, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(P.T @ basis.project(B), 0.0, atol=1e-9)
    assert LinearBasis(Phi).full and not LinearBasis(np.hstack([Phi, Phi[:, :1]])).full


def test_regressors_at_drawn_rows_equal_those_rows_of_the_whole_lag_matrix():
    from enginebench.methods.freerun import Trajectory
    from enginebench.methods.narx_model import mimo_regressors, regression_count, regressors

    rng = np.random.default_rng(0)
    traj = [Trajectory(f"s{i}", rng.normal(size=(n, 2)), rng.normal(size=(n, 3))) for i, n in enumerate((50, 3, 40, 9))]
    na, nb, nk = 4, 3, 2
    count = regression_count(traj, na, nb, nk)
    Z, y = regressors(traj, 1, na, nb, nk)
    assert count == len(y) == (50 - 4) + (40 - 4) + (9 - 4)
    rows = np.sort(rng.choice(count, size=30, replace=False))
    Zr, yr = regressors(traj, 1, na, nb, nk, rows)
    assert Zr.tobytes() == Z[rows].tobytes() and yr.tobytes() == y[rows].tobytes()
    Zm, Ym = mimo_regressors(traj, na, nb, nk)
    Zmr, Ymr = mimo_regressors(traj, na, nb, nk, rows)
    assert Zmr.tobytes() == Zm[rows].tobytes() and Ymr.tobytes() == Ym[rows].tobytes()


@pytest.fixture(scope="module")
def boxed(data) -> NARXFit:
    """The fixture's model with ``kernel_box = true`` (off by default)."""
    return NARX(kernel_box=True).fit(data[0], PARAMS, np.random.default_rng(0))


@pytest.fixture(scope="module")
def beyond() -> Samples:
    """Two records driven at twice the training amplitude: inputs and outputs leave the training range."""
    return samples(nonlinear_raw(2, 300, seed=6, amplitude=3.0), init_samples=5)


def test_beyond_the_training_range_the_kernel_reads_its_edge(fitted, boxed, beyond):
    """The free run (batched over segments, and one segment alone) equals the reference with z(t) clipped to the
    kernel box; the box is the training data's range, and it changes the run here (without it, the reference
    unclipped)."""
    assert fitted.box is None and NARX().describe(fitted)["kernel_box"] is None  # off by default
    np.testing.assert_array_equal(boxed.models[0].beta, fitted.models[0].beta)  # the fit is the same
    train, fitted = samples(nonlinear_raw(3, 200, seed=0)), boxed
    box = fitted.box
    U, Y = np.vstack([s.U for s in train.segments]), np.vstack([s.y for s in train.segments])
    np.testing.assert_allclose(NARX().describe(fitted)["kernel_box"]["inputs"], [[U.min(), U.max()]], rtol=1e-12)
    np.testing.assert_allclose(box.u_lo * fitted.u_std + fitted.u_mean, U.min(axis=0), rtol=1e-12)
    np.testing.assert_allclose(box.y_hi * fitted.y_std + fitted.y_mean, Y.max(axis=0), rtol=1e-12)
    view = beyond.without_targets()
    pred = NARX().predict(fitted, view)
    unclipped = NARX(kernel_box=False).predict(replace(fitted, box=None), view)
    for k, seg in enumerate(beyond.segments):
        assert np.abs(seg.U).max() > np.abs(U).max() * 1.5
        np.testing.assert_allclose(pred[k][:, 0], reference_run(fitted, seg.U, seg.y_init)[5:], rtol=0, atol=1e-10)
        alone = NARX().predict(fitted, replace(view, segments=(view.segments[k],)))
        np.testing.assert_allclose(alone[0], pred[k], rtol=0, atol=1e-10)
        np.testing.assert_allclose(unclipped[k][:, 0], reference_run(replace(fitted, box=None), seg.U, seg.y_init)[5:],
                                   rtol=0, atol=1e-9)
        assert np.abs(unclipped[k] - pred[k]).max() > 1e-3


def test_without_the_linear_part_inputs_past_the_range_act_as_the_range_edge():
    """linear = false: the model reads the inputs only through the kernel, so driving it past the training range
    gives exactly the run of the inputs clipped to that range."""
    train = samples(nonlinear_raw(3, 200, seed=0))
    fit = NARX(linear=False, kernel_box=True).fit(train, PARAMS, np.random.default_rng(0))
    far = samples(nonlinear_raw(1, 300, seed=7, amplitude=4.0)).without_targets()
    lo, hi = (fit.box.u_lo * fit.u_std + fit.u_mean)[0], (fit.box.u_hi * fit.u_std + fit.u_mean)[0]
    edge = replace(far, segments=tuple(replace(s, U=np.clip(s.U, lo, hi)) for s in far.segments))
    assert (np.abs(far.segments[0].U) > 1.5).mean() > 0.4
    np.testing.assert_array_equal(NARX(linear=False).predict(fit, far)[0], NARX(linear=False).predict(fit, edge)[0])
    assert not np.array_equal(NARX(linear=False).predict(replace(fit, box=None), far)[0],
                              NARX(linear=False).predict(replace(fit, box=None), edge)[0])


def test_the_c_step_clips_the_kernel_regressors_as_the_free_run_does(boxed, beyond):
    from enginebench.methods.export.harness import compiler, run_c

    if compiler() is None:
        pytest.skip("no C compiler (gcc or cc) on this machine")
    view = beyond.without_targets()
    for fit in (boxed, replace(boxed, box=None)):
        model = NARX().c_model(fit)
        assert ("eb_clip(" in model.body) == (fit.box is not None)
        for seg, pred in zip(view.segments, NARX().predict(fit, view)):
            Y, _, diverged = run_c(model, seg.U, seg.y_init, len(seg.y_init))
            assert not diverged
            np.testing.assert_allclose(Y[len(seg.y_init):], pred, rtol=0, atol=1e-9 * np.abs(pred).max())


@pytest.mark.parametrize("shared", [False, True])
def test_a_row_subsample_fits_the_kernel_and_every_row_the_linear_part(shared):
    """With more regression rows than ``max_rows`` the kernel is solved on a subsample and the linear part is
    fitted again on every row with the kernel sum held fixed: theta equals the least squares of the whole lag
    matrix against y - K(z, C) beta (numpy's lstsq), here in several of the streamed QR's blocks."""
    from enginebench.methods.freerun import training_trajectories
    from enginebench.methods.narx_model import linear_on_all_rows, mimo_regressors, regressors, standardise
    from enginebench.methods.numerics.kernels import gaussian, sq_distances

    train = samples(nonlinear_raw(3, 200, seed=0))
    two = SamplePool(RawSegments.from_dataset(_two_outputs(nonlinear_raw(3, 200, seed=0))), ["y", "y2"],
                     "simulation").materialize()
    data = two if shared else train
    fit = NARX(max_rows=150, shared_kernel=shared).fit(data, PARAMS, np.random.default_rng(0))
    std = standardise(training_trajectories("narx", data), 1.0)
    na = nb = 2
    Z, y = mimo_regressors(std.traj, na, nb, 0) if shared else regressors(std.traj, 0, na, nb, 0)
    assert len(y) == 3 * 198 and fit.info["linear_rows"] == len(y) and fit.n_rows == 150
    m = fit.mimo if shared else fit.models[0]
    K = gaussian(sq_distances(Z, m.centres), m.gamma / m.d)  # ka = na, kb = nb: the kernel reads every lag
    want = np.linalg.lstsq(np.hstack([Z, np.ones((len(Z), 1))]), y - K @ m.beta, rcond=None)[0]
    if shared:
        got_a = np.stack([want[[p * na + na - lag for p in range(2)]] for lag in range(1, na + 1)])
        np.testing.assert_allclose(m.a, got_a, rtol=0, atol=1e-9)
        np.testing.assert_allclose(m.c0, want[-1], rtol=0, atol=1e-9)
    else:
        np.testing.assert_allclose(np.r_[m.a[::-1], m.b.ravel(), m.c0], want, rtol=0, atol=1e-9)
    # the streamed QR in blocks of 50 rows equals one solve
    build = (lambda r: mimo_regressors(std.traj, na, nb, 0, rows=r)) if shared else \
        (lambda r: regressors(std.traj, 0, na, nb, 0, rows=r))
    cols = list(range(Z.shape[1]))
    whole = linear_on_all_rows(build, len(y), cols, m.centres, [(m.gamma / m.d, m.beta)], block_rows=len(y))[0]
    blocks = linear_on_all_rows(build, len(y), cols, m.centres, [(m.gamma / m.d, m.beta)], block_rows=50)[0]
    np.testing.assert_allclose(blocks, whole, rtol=0, atol=1e-10)
    np.testing.assert_allclose(whole.reshape(len(want), -1), want.reshape(len(want), -1), rtol=0, atol=1e-9)


def _two_outputs(raw: RawSegments) -> Dataset:
    """``raw``'s records with a second output, y2(t) = 0.5 y(t-1)^2 (the MIMO path needs two)."""
    frames = []
    for seg in raw.segments:
        y = seg.Y[:, 0]
        frames.append(pd.DataFrame({"segment": seg.id, "time": seg.t, "u": seg.U[:, 0], "y": y,
                                    "y2": 0.5 * np.r_[y[0], y[:-1]] ** 2}))
    return Dataset("nl2", pd.concat(frames, ignore_index=True),
                   Schema.from_roles({"u": "input", "y": "output", "y2": "output"}), 1.0)
