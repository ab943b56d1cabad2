"""Cascades: upstream model of an intermediate -> downstream model of the target (turboshaft-moe's WF -> TRQ)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from enginebench import registry
from enginebench.datasets.dataset import Dataset
from enginebench.datasets.pools import make_samples
from enginebench.datasets.schema import Schema
from enginebench.errors import MethodError
from enginebench.method import grid_points
from enginebench.methods.cascade import Cascade, MoEIdeal, MoEMoE, MoENFIR, SINDyIdeal, SINDyNFIR
from enginebench.methods.cascade_components import Initialiser, target_samples, with_inputs
from enginebench.methods.nfir import NFIR

DT = 0.5
NF = {"horizon": 2.0, "stride": 2, "gamma": 0.5, "lambda": 1e-2}
NF2 = {"horizon": 1.0, "stride": 1, "gamma": 0.2, "lambda": 1e-3}


def engine_dataset(w_role: str, n_seg: int = 5, n: int = 90, seed: int = 0) -> Dataset:
    """Controls u1, u2 -> fuel-like w (a lagged map of u) -> torque-like y, a first-order lag of w."""
    rng = np.random.default_rng(seed)
    frames = []
    for s in range(n_seg):
        u1 = 1.0 + np.cumsum(rng.normal(0, 0.1, n))
        u2 = rng.uniform(-1, 1, n)
        w = 2.0 + u1 + 0.3 * np.r_[u2[0], u2[:-1]] + rng.normal(0, 0.01, n)
        y = np.empty(n)
        y[0] = 1.5 * w[0]
        for i in range(1, n):
            y[i] = y[i - 1] + DT / 2.0 * (1.5 * w[i - 1] - y[i - 1])
        lag = lambda x, k: np.r_[np.full(k, x[0]), x[:-k]]  # noqa: E731
        g = (u1 + lag(u1, 2) + lag(u1, 4)) / 3  # a slow internal state, like NG
        frames.append(pd.DataFrame({"segment": f"s{s}", "time": np.arange(n) * DT, "u1": u1, "u2": u2, "w": w, "y": y, "g": g}))
    schema = Schema.from_roles({"u1": "input", "u2": "input", "w": w_role, "y": "output", "g": "internal"})
    return Dataset("cascade-toy", pd.concat(frames, ignore_index=True), schema, DT)


def split(w_role: str):
    sim = make_samples(engine_dataset(w_role), ["y"], "simulation")
    cut = sum(len(s) for s in sim.segments[:3])
    return sim.take(np.arange(cut)), sim.take(np.arange(cut, len(sim)))


@pytest.fixture(scope="module")
def internal():
    return split("internal")


def nfir_cascade(**kw) -> Cascade:
    opts = dict(upstream="nfir", downstream="nfir", intermediate="w", upstream_params=NF,
                upstream_options={"max_rows": 0}, downstream_options={"max_rows": 0})
    return Cascade(**{**opts, **kw})


# -- the plumbing against a hand-made pipeline ------------------------------------------------------
def test_model_source_equals_the_hand_made_chain(internal):
    train, test = internal
    fitted = nfir_cascade().fit(train, NF2, np.random.default_rng(0))
    pred = np.concatenate(nfir_cascade().predict(fitted, test.without_targets()))

    # by hand: NFIR u -> w on the training trajectories, then NFIR [u, w_hat] -> y
    rng = np.random.default_rng(0)
    w_true = [s.Z[:, list(train.internal_names).index("w")] for s in train.segments]
    up_train = target_samples(train, "w", ("u1", "u2"), w_true, [w[0] for w in w_true])
    up = NFIR(max_rows=0)
    up_fit = up.fit(up_train, NF, rng)

    def with_w(data):
        part = target_samples(data, "w", ("u1", "u2"), None, [np.zeros(1)] * len(data.segments))
        w_hat = up.predict(up_fit, part)
        return with_inputs(data, ("u1", "u2", "w"), [np.column_stack([s.U, wh[:, 0]]) for s, wh in zip(data.segments, w_hat)])

    down = NFIR(max_rows=0)
    down_fit = down.fit(with_w(train), NF2, rng)
    ref = np.concatenate(down.predict(down_fit, with_w(test.without_targets())))
    np.testing.assert_allclose(pred, ref, rtol=1e-12, atol=1e-12)
    assert fitted.upstreams[0].search == {"grid_size": 1}  # every upstream hyperparameter fixed: no inner search


def test_train_on_true_feeds_the_measured_intermediate_in_training(internal):
    train, test = internal
    c = nfir_cascade(train_on="true")
    fitted = c.fit(train, NF2, np.random.default_rng(0))
    down = NFIR(max_rows=0)
    j = list(train.internal_names).index("w")
    measured = with_inputs(train, ("u1", "u2", "w"), [np.column_stack([s.U, s.Z[:, j]]) for s in train.segments])
    ref_fit = down.fit(measured, NF2, np.random.default_rng(0))
    np.testing.assert_allclose(fitted.fitted.krls.alpha, ref_fit.krls.alpha, rtol=1e-12, atol=1e-12)
    assert c.describe(fitted)["train_on"] == "true"


def test_prediction_never_reads_the_internal_columns(internal):
    train, test = internal
    c = nfir_cascade()
    fitted = c.fit(train, NF2, np.random.default_rng(0))
    a = np.concatenate(c.predict(fitted, test.without_targets()))
    poisoned = replace(test, segments=tuple(replace(s, Z=s.Z * 0 + 1e9) for s in test.segments))
    b = np.concatenate(c.predict(fitted, poisoned))
    np.testing.assert_array_equal(a, b)
    assert c.describe(fitted)["available_at_run_time"] is True


def test_grid_over_the_downstream_equals_each_point(internal):
    train, test = internal
    c = nfir_cascade(downstream_options={"max_rows": 0, "horizons": [1.0], "strides": [1], "gamma_grid": (-1, 0, 2),
                                         "lambda_grid": (-3, -3, 1)})
    grid = grid_points(c.search_space(train))
    assert len(grid) == 2
    out = c.predict_grid(train, test.without_targets(), grid, np.random.default_rng(0))
    for i, p in enumerate(grid):
        f = c.fit(train, p, np.random.default_rng(0))
        np.testing.assert_allclose(out[i], np.concatenate(c.predict(f, test.without_targets())), rtol=1e-10, atol=1e-12)


def test_upstream_is_tuned_on_a_holdout_of_training_trajectories(internal):
    train, _ = internal
    c = nfir_cascade(upstream_params={"horizon": 1.0, "stride": 1}, upstream_options={"max_rows": 0, "gamma_grid": (-2, 0, 3),
                                                                                     "lambda_grid": (-4, -1, 2)})
    fitted = c.fit(train, NF2, np.random.default_rng(0))
    search = fitted.upstreams[0].search
    assert search["grid_size"] == 6 and search["holdout_segments"] == 1  # ceil(0.25 * 3) trajectories
    assert fitted.upstreams[0].params["horizon"] == 1.0 and fitted.upstreams[0].params["gamma"] in (0.01, 0.1, 1.0)


def test_an_nfir_upstream_derives_its_horizons_from_the_intermediate(internal):
    """Default upstream options: the horizons come from w's memory (a lag of u2 by one sample), in samples."""
    train, test = internal
    c = nfir_cascade(upstream_params={"gamma": 0.5, "lambda": 1e-2})
    fitted = c.fit(train, NF2, np.random.default_rng(0))
    up = c.describe(fitted)["upstream"][0]
    derived = up["horizons_derived"]
    assert derived["grid_samples"] and up["horizon_samples"] in derived["grid_samples"]
    assert fitted.upstreams[0].search["grid_size"] == len(derived["grid_samples"])
    assert up["horizon_s"] == pytest.approx(up["horizon_samples"] * DT)
    assert np.isfinite(np.concatenate(c.predict(fitted, test.without_targets()))).all()


def test_surrogates_feed_both_upstream_and_downstream(internal):
    train, test = internal
    c = nfir_cascade(surrogates=["g"], surrogate_params=NF, surrogate_options={"max_rows": 0})
    fitted = c.fit(train, NF2, np.random.default_rng(0))
    sur, up = fitted.upstreams
    assert (sur.name, sur.inputs) == ("g", ("u1", "u2"))  # the surrogate sees run-time inputs only
    assert (up.name, up.inputs) == ("w", ("u1", "u2", "g"))
    assert fitted.down_inputs == ("u1", "u2", "g", "w")
    a = np.concatenate(c.predict(fitted, test.without_targets()))
    poisoned = replace(test, segments=tuple(replace(s, Z=s.Z * 0 + 1e9) for s in test.segments))
    np.testing.assert_array_equal(a, np.concatenate(c.predict(fitted, poisoned)))
    g_hat = c.intermediate_predictions(fitted, test.without_targets())["g"]
    g_true = np.concatenate([s.Z[:, list(test.internal_names).index("g")] for s in test.segments])
    assert np.corrcoef(np.concatenate(g_hat), g_true)[0, 1] > 0.9  # a fair reconstruction of the internal state
    assert c.describe(fitted)["surrogates"][0]["signal"] == "g"


# -- ideal rows ------------------------------------------------------------------------------------
def test_ideal_equals_the_plain_downstream_with_the_measured_input():
    train, test = split("input")
    c = Cascade(source="true", downstream="nfir", intermediate="w", downstream_options={"max_rows": 0})
    fitted = c.fit(train, NF2, np.random.default_rng(0))
    pred = np.concatenate(c.predict(fitted, test.without_targets()))
    plain = NFIR(max_rows=0)
    ref = np.concatenate(plain.predict(plain.fit(train, NF2, np.random.default_rng(0)), test.without_targets()))
    np.testing.assert_allclose(pred, ref, rtol=1e-12, atol=1e-12)  # inputs u1, u2, w in the same order
    d = c.describe(fitted)
    assert d["available_at_run_time"] is False and "not available at run time" in d["note"]


def test_ideal_in_an_experiment_where_the_intermediate_is_internal_is_refused(internal):
    train, _ = internal
    with pytest.raises(MethodError, match=r"w must be a run-time input of the experiment; here it is internal: "
                                          r"set roles = \{ w = \"input\" \}"):
        Cascade(source="true", downstream="nfir", intermediate="w").fit(train, NF2, np.random.default_rng(0))


def test_missing_intermediate_names_the_role_to_give():
    sim = make_samples(engine_dataset("output"), ["y"], "simulation")
    with pytest.raises(MethodError, match=r"no column 'w' .* give w the role 'internal'"):
        nfir_cascade().fit(sim, NF2, np.random.default_rng(0))


# -- names, presets, options ---------------------------------------------------------------------------
def test_named_cascades_read_like_the_seeds_table_3():
    assert {c.name for c in (MoENFIR, SINDyNFIR, MoEMoE, MoEIdeal, SINDyIdeal)} == {
        "moe-nfir", "sindy-nfir", "moe-moe", "moe[ideal]", "sindy[ideal]"}
    assert MoENFIR().options["upstream"] == "nfir" and MoENFIR().options["downstream"] == "moe"
    assert MoEMoE().options["upstream"] == "moe" and SINDyNFIR().options["downstream"] == "sindy"
    assert MoEIdeal().options["source"] == "true" and "[ideal]" in SINDyIdeal.name
    for cls in (MoENFIR, MoEIdeal):
        registry.register(cls)
        assert registry.get(cls.name) is cls


@pytest.mark.parametrize("options, fragment", [
    ({"source": "measured"}, "option source='measured'; use 'model'"),
    ({"train_on": "x"}, "option train_on='x'"),
    ({"intermediate": []}, "option intermediate=\\[\\] must be a column name"),
    ({"upstream_holdout": 1.0}, "upstream_holdout must lie strictly between 0 and 1"),
    ({"upstream": "nope"}, "unknown method 'nope'"),
    ({"downstream_options": {"colour": 1}}, "unknown option\\(s\\) colour"),
    ({"surrogates": ["WF"], "intermediate": "WF"}, "option surrogates=\\['WF'\\] must be a list of distinct"),
])
def test_bad_options_are_refused(options, fragment):
    with pytest.raises(MethodError, match=fragment):
        Cascade(**options)


def test_initialiser_recovers_an_exact_linear_relation():
    rng = np.random.default_rng(0)
    F = rng.normal(size=(200, 3))
    z = 2.0 * F[:, 0] - 0.5 * F[:, 2] + 3.0
    init = Initialiser.fit(F, z, ridge=1e-12)
    np.testing.assert_allclose(init(F[:5]), z[:5], rtol=1e-8)


# -- a real MoE downstream (tiny) -------------------------------------------------------------------------
def test_moe_nfir_constrains_the_intermediate_positive_and_exposes_gates(internal):
    from enginebench.methods.moe import gate_weights

    train, test = internal
    c = MoENFIR(intermediate="w", upstream_params=NF, downstream_options={"cpu_threads": 1})
    hp = {"n_experts": 2, "beta1": 1.0, "beta2": 1.0, "k": 1.0, "gate_hidden": 4, "lr": 1e-2, "epochs": 2}
    fitted = c.fit(train, hp, np.random.default_rng(0))
    preds = c.predict(fitted, test.without_targets())
    assert all(np.isfinite(p).all() and p.shape == (len(s), 1) for p, s in zip(preds, test.segments))
    signs = c.describe(fitted)["downstream"]["signs"]
    assert signs == {"dy/dt <- y": "-", "dy/dt <- w": "+"}  # turboshaft-moe: own state negative, fuel positive
    down, down_fitted, down_data = c.downstream_view(fitted, test.without_targets())
    assert down_data.input_names == ("u1", "u2", "w")
    gates = gate_weights(down_fitted, down_data)
    np.testing.assert_allclose(np.concatenate(gates).sum(axis=1), 1.0, rtol=1e-5)
    w_hat = c.intermediate_predictions(fitted, test.without_targets())["w"]
    assert [len(w) for w in w_hat] == [len(s) for s in test.segments]


def test_a_moe_downstream_grid_shares_the_upstream_and_one_training_run_per_point(internal):
    import pickle

    train, test = internal
    c = MoENFIR(intermediate="w", upstream_params=NF, downstream_options={"cpu_threads": 1})
    assert c.keeps_grid_models() and not nfir_cascade().keeps_grid_models()
    hp = {"n_experts": 2, "beta1": 1.0, "beta2": 1.0, "k": 1.0, "gate_hidden": 4, "lr": 1e-2}
    grid = [{**hp, "epochs": 3}, {**hp, "epochs": 1}]
    view = test.without_targets()
    models = dict(c.fit_grid(train, grid, np.random.default_rng(0)))
    assert models[0].upstreams is models[1].upstreams  # the upstream NFIR is fitted once for the grid
    assert [len(models[i].fitted.loss_history) for i in (0, 1)] == [3, 1]
    assert models[1].fitted.loss_history == models[0].fitted.loss_history[:1]  # one run, packed after 1 and 3 epochs
    out = c.predict_grid(train, view, grid, np.random.default_rng(0))
    for i, params in enumerate(grid):  # each point as a fit of its own from the same draws
        alone = c.fit(train, params, np.random.default_rng(0))
        np.testing.assert_array_equal(out[i], np.concatenate(c.predict(alone, view)))
    shared = models[0]
    c.predict(shared, view)
    assert shared.shared["data"] is view and pickle.loads(pickle.dumps(shared)).shared == {}
