"""enginebench.testing.check_method: built-in methods pass it; broken methods fail it with the right message."""

from __future__ import annotations

import numpy as np
import pytest

from enginebench import registry
from enginebench.errors import DataError, MethodError
from enginebench.method import Method, SegmentPredictions
from enginebench.samples import Samples
from enginebench.testing import CHECKS, TINY_INIT, ConformanceError, check_method, tiny_samples

# every registered method, in each of its modes: test_conformance_registry.py


def test_simulation_only_methods_get_the_whole_suite():
    report = check_method(registry.get("sindy"), {"derivative": "kalman", "degrees": (1,), "n_thresholds": 1})
    assert report.modes == ("simulation",) and not report.skipped
    assert report.passed == ["attributes", "options"] + [f"{c}[simulation]" for c in (
        "no-target-leakage", "determinism", "shapes", "pickle-round-trip", "bad-input")]


# -- broken methods --------------------------------------------------------------------------

class MeanBase(Method):
    """Training mean, with a checked feature count; the broken methods below change one thing."""

    name = "test-mean"
    family = "baseline"
    modes = frozenset({"static"})

    def fit(self, train: Samples, params, rng: np.random.Generator):
        return {"mean": train.y.mean(axis=0), "d": train.X.shape[1]}

    def predict(self, fitted, data: Samples) -> list[np.ndarray]:
        if data.X.shape[1] != fitted["d"]:
            raise MethodError(f"{self.name}: wrong feature count")
        return [np.tile(fitted["mean"], (len(s), 1)) for s in data.segments]


# (module level: a method must pickle by reference to reach worker processes)

class Jitter(MeanBase):
    name = "test-jitter"

    def fit(self, train, params, rng):
        fitted = super().fit(train, params, rng)
        fitted["mean"] = fitted["mean"] + np.random.default_rng().normal(0, 1e-3)  # not from rng
        return fitted


class Peek(MeanBase):
    name = "test-peek"

    def predict(self, fitted, data):
        return [s.y.reshape(len(s), -1) if s.y is not None else np.asarray(data.y) for s in data.segments]


class QuietPeek(MeanBase):
    name = "test-peek-quietly"

    def predict(self, fitted, data):
        return [s.y.reshape(len(s), -1) if s.y is not None else np.tile(fitted["mean"], (len(s), 1))
                for s in data.segments]


class Flat(MeanBase):
    name = "test-flat"

    def predict(self, fitted, data):
        return [np.full(len(s), fitted["mean"][0]) for s in data.segments]


class BadGrid(MeanBase):
    name = "test-bad-grid"

    def search_space(self, data):
        return {"c": np.array([1.0, 2.0])}

    def predict_grid(self, train, data, grid, rng):
        return np.zeros((len(data), len(grid)))


class Closure(MeanBase):
    name = "test-closure"

    def fit(self, train, params, rng):
        fitted = super().fit(train, params, rng)
        fitted["f"] = lambda x: x
        return fitted


class Unchecked(MeanBase):
    name = "test-unchecked"

    def predict(self, fitted, data):
        w = np.ones((fitted["d"], 1))
        return [s.X @ w * 0 + fitted["mean"] for s in data.segments]  # NaN passes through; shapes clash


class NoCount(MeanBase):
    name = "test-no-count"

    def predict(self, fitted, data):
        if not np.isfinite(data.X).all():
            raise MethodError("non-finite features")
        w = np.ones((fitted["d"], 1))
        return [s.X @ w * 0 + fitted["mean"] for s in data.segments]


class Magic(MeanBase):
    name = "test-magic"
    family = "magic"


class Lax(MeanBase):
    name = "test-lax"

    def __init__(self, **options):
        self.options = dict(options)


class HoldInit(Method):
    """Simulation mode done right: hold the last measured output of the init window (y0 without one)."""

    name = "test-hold"
    family = "baseline"
    modes = frozenset({"simulation"})

    def fit(self, train, params, rng):
        return {"inputs": train.input_names}

    def _start(self, s):
        if s.y_init is not None and len(s.y_init):
            return np.asarray(s.y_init[-1], dtype=float)
        return np.asarray(s.y0, dtype=float)

    def predict(self, fitted, data):
        if tuple(data.input_names) != tuple(fitted["inputs"]):
            raise MethodError(f"{self.name}: inputs {data.input_names} differ from the fitted {fitted['inputs']}")
        starts = [self._start(s) for s in data.segments]
        if not all(np.isfinite(v).all() for v in starts):
            raise MethodError(f"{self.name}: non-finite initial output")
        return SegmentPredictions([np.tile(v, (len(s), 1)) for v, s in zip(starts, data.segments)])


class PlainList(HoldInit):
    name = "test-plain-list"

    def predict(self, fitted, data):
        return list(super().predict(fitted, data))


class BadFlags(HoldInit):
    name = "test-bad-flags"

    def predict(self, fitted, data):
        preds = super().predict(fitted, data)
        preds.diverged = np.zeros(len(preds))  # floats, not bools
        return preds


class WholeSegment(HoldInit):
    name = "test-whole-segment"

    def predict(self, fitted, data):  # a row for the init window too
        return SegmentPredictions([np.tile(self._start(s), (len(s.U), 1)) for s in data.segments])


class PeekAfterWindow(HoldInit):
    name = "test-peek-after-window"

    def predict(self, fitted, data):
        preds = super().predict(fitted, data)
        return SegmentPredictions([p if s.y is None else p + 0 * s.y + s.y[-1] for p, s in zip(preds, data.segments)])


class CrashOnNaNInit(HoldInit):
    name = "test-crash-on-nan-init"

    def predict(self, fitted, data):
        for s in data.segments:
            if s.y_init is not None and not np.isfinite(s.y_init).all():
                raise ValueError("cannot convert float NaN to integer")
        return super().predict(fitted, data)


def test_a_simulating_method_that_uses_the_init_window_passes():
    report = check_method(HoldInit)
    assert report.passed[-1] == "bad-input[simulation]"


def test_simulating_methods_must_return_segment_predictions_with_bool_flags():
    failures = failures_of(PlainList)
    assert failures["shapes"] == [
        "[shapes] method 'test-plain-list' (simulation mode): predict returned list, not SegmentPredictions; a "
        "simulating method returns SegmentPredictions(arrays, diverged=flags) (enginebench.method), one flag "
        "per segment"]
    failures = failures_of(BadFlags)
    assert "returned diverged flags of dtype float64 and shape (2,); expected one bool per segment, shape (2,)" \
        in failures["shapes"][0]


def test_predictions_must_skip_the_init_window():
    failures = failures_of(WholeSegment)
    assert failures["shapes"][0].startswith(
        "[shapes] method 'test-whole-segment' (simulation mode): predict returned shape (25, 1) for segment 's3'; "
        "expected (22, 1)")


def test_measured_outputs_after_the_window_reaching_predict_fail_leakage(monkeypatch):
    monkeypatch.setattr(Samples, "without_targets", lambda self: self)
    failures = failures_of(PeekAfterWindow)
    assert failures["no-target-leakage"] == [
        "[no-target-leakage] method 'test-peek-after-window' (simulation mode): changing the measured outputs after "
        "the initialisation window (the first 3 samples, y_init) changed the predictions: a simulation may use y0 "
        "and y_init only, then runs free on the inputs"]


def test_a_traceback_on_a_nan_init_window_fails_bad_input():
    failures = failures_of(CrashOnNaNInit)
    assert list(failures) == ["bad-input"]
    assert failures["bad-input"][0].startswith(
        "[bad-input] method 'test-crash-on-nan-init' (simulation mode): predict with a NaN in the initialisation "
        "window (y_init) raised ValueError: cannot convert float NaN to integer, a bare traceback for the user")


def test_fixed_params_replace_their_grid():
    seen = []

    class Recorder(HoldInit):
        name = "test-recorder"

        def search_space(self, data):
            return {"a": np.array([1, 2, 3]), "b": np.array([10.0, 20.0])}

        def fit(self, train, params, rng):
            seen.append(dict(params))
            return super().fit(train, params, rng)

    with pytest.raises(ConformanceError, match="pickle"):  # a local class does not pickle by reference
        check_method(Recorder, params={"b": 5.0})
    assert seen and all(p["b"] == 5.0 and p["a"] in (1, 2, 3) for p in seen)


def failures_of(cls: type[Method]) -> dict[str, list[str]]:
    with pytest.raises(ConformanceError) as info:
        check_method(cls)
    out: dict[str, list[str]] = {}
    for check, message in info.value.failures:
        out.setdefault(check, []).append(message)
    assert str(info.value).startswith(f"method {cls.name!r} failed {len(out)} of {len(CHECKS)} conformance checks:")
    return out


def test_the_well_behaved_base_passes():
    assert check_method(MeanBase).passed[-1] == "bad-input[static]"


def test_a_non_deterministic_method_fails_determinism():
    failures = failures_of(Jitter)
    assert list(failures) == ["determinism"]
    (message,) = failures["determinism"]
    assert message.startswith("[determinism] method 'test-jitter' (static mode): fit + predict twice with the same "
                              "seed gave different predictions")
    assert "only from the rng argument of fit" in message


def test_a_method_reading_the_targets_fails_leakage():
    failures = failures_of(Peek)
    assert "no-target-leakage" in failures
    assert failures["no-target-leakage"][0] == (
        "[no-target-leakage] method 'test-peek' (static mode): predict read the targets of the samples it must "
        "predict (data.y), which are removed before predict; use only data.X, data.U and data.t")


def test_targets_reaching_predict_by_another_way_fail_leakage(monkeypatch):
    """If the targets got through to predict (here: a pipeline that forgot to remove them),
    the perturbation check still catches a method that uses them."""
    monkeypatch.setattr(Samples, "without_targets", lambda self: self)
    failures = failures_of(QuietPeek)
    assert failures["no-target-leakage"] == [
        "[no-target-leakage] method 'test-peek-quietly' (static mode): changing the targets of the evaluated rows "
        "(never features) changed the predictions: the method reads what it must predict"]


def test_wrong_shapes_fail_shapes():
    failures = failures_of(Flat)
    assert failures["shapes"][0].startswith("[shapes] method 'test-flat' (static mode): predict returned shape (25,) "
                                            "for segment 's3'; expected (25, 1)")


def test_a_wrong_predict_grid_shape_fails_shapes():
    failures = failures_of(BadGrid)
    assert list(failures) == ["shapes"]
    assert "predict_grid over 2 grid points returned shape (50, 2); expected (2, 50, 1)" in failures["shapes"][0]


def test_an_unpicklable_fitted_model_fails_the_round_trip():
    failures = failures_of(Closure)
    assert list(failures) == ["pickle-round-trip"]
    assert "pickling the method or its fitted model failed" in failures["pickle-round-trip"][0]


def test_a_bare_traceback_on_bad_input_fails():
    failures = failures_of(Unchecked)
    assert list(failures) == ["bad-input"]
    message = failures["bad-input"][0]
    assert message.startswith("[bad-input] method 'test-unchecked' (static mode): predict with a NaN feature "
                              "returned non-finite predictions instead of raising MethodError")


def test_a_bare_value_error_on_a_wrong_feature_count_fails():
    failures = failures_of(NoCount)
    assert list(failures) == ["bad-input"]
    assert "predict with 1 feature columns (trained on 2) raised ValueError" in failures["bad-input"][0]
    assert "a bare traceback for the user" in failures["bad-input"][0]


def test_bad_class_attributes_stop_the_suite():
    with pytest.raises(ConformanceError) as info:
        check_method(Magic)
    assert info.value.failures == [("attributes", "[attributes] method 'test-magic': family 'magic' is not one of "
                                                  "physical, data-driven, hybrid, baseline")]


def test_silently_accepted_unknown_options_fail():
    failures = failures_of(Lax)
    assert list(failures) == ["options"]
    assert "was accepted silently" in failures["options"][0]


def test_tiny_simulation_samples_carry_the_init_window():
    train, test = tiny_samples("simulation")
    assert train.init_samples == 0 and [s.rows.tolist() for s in train.segments] == [list(range(30))] * 3
    assert test.init_samples == TINY_INIT == 3
    for s in test.segments:
        assert s.rows.tolist() == list(range(3, 25)) and s.y_init.shape == (3, 1) and len(s.U) == 25
        np.testing.assert_array_equal(s.y0, s.y_init[0])
    view = test.without_targets()
    assert view.segments[0].y is None and view.segments[0].y_init.shape == (3, 1)


def test_tiny_samples_shapes():
    train, test = tiny_samples("window")
    assert len(train.segments) == 3 and len(test.segments) == 2
    assert train.feature_names == ("u1[t]", "u1[t-1]", "u1[t-2]", "u2[t]", "u2[t-1]", "u2[t-2]", "y[t-1]", "y[t-2]")
    assert len(test) == 2 * (25 - 2)
    assert train.physical_model is not None


def test_extra_columns_join_the_tiny_data_in_their_role_and_change_nothing_else():
    plain_train, plain_test = tiny_samples("simulation")
    train, test = tiny_samples("simulation", roles={"w": "internal"})
    assert train.input_names == ("u1", "u2") and train.internal_names == ("w",)
    assert train.segments[0].Z.shape == (30, 1) and np.isfinite(train.segments[0].Z).all()
    assert test.without_targets().segments[0].Z is None  # measured in training only
    for a, b in zip(plain_train.segments + plain_test.segments, train.segments + test.segments):
        np.testing.assert_array_equal(a.U, b.U)
        np.testing.assert_array_equal(a.y, b.y)
    static, _ = tiny_samples("static", roles={"w": "input", "v": "internal"})
    assert static.input_names == ("u1", "u2", "w") and static.internal_names == ("v",)
    assert "w" in static.feature_names
    w, v = static.segments[0].X[:, static.feature_names.index("w")], static.segments[0].Z[:, 0]
    assert not np.allclose(w, v)  # each extra column is a signal of its own


@pytest.mark.parametrize("roles, match", [({"y": "internal"}, "already a column"), ({"w": "output"}, "role 'output'")])
def test_a_bad_extra_column_is_refused(roles, match):
    with pytest.raises(DataError, match=match):
        tiny_samples("static", roles=roles)


def test_mode_checks_one_declared_mode():
    report = check_method(registry.get("naive-mean"), mode="window")
    assert report.modes == ("window",)
    assert report.passed == ["attributes", "options"] + [f"{c}[window]" for c in (
        "no-target-leakage", "determinism", "shapes", "pickle-round-trip", "bad-input")]
    with pytest.raises(MethodError, match="declares no checked mode 'simulation'; its modes: window"):
        check_method(registry.get("naive-last"), mode="simulation")


def test_a_method_that_reads_an_internal_column_at_prediction_fails():
    class UsesZ(Method):
        name = "test-uses-z"
        family = "baseline"
        modes = frozenset({"static"})

        def fit(self, train: Samples, params, rng: np.random.Generator):
            return {"d": train.X.shape[1]}

        def predict(self, fitted, data: Samples):
            return [s.Z[:, :1] for s in data.segments]  # Z is measured in training only

    with pytest.raises(ConformanceError, match=r"predict raised TypeError"):
        check_method(UsesZ, roles={"w": "internal"})


def test_the_readme_example_method_conforms(tmp_path, monkeypatch):
    """The Method example under README's 'Writing a method' passes the suite it advertises."""
    import importlib
    import re
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    section = readme[readme.index("## Writing a method"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    (tmp_path / "readme_ridge_example.py").write_text(code)  # a real module, so the class pickles by reference
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("readme_ridge_example")
    report = check_method(module.Ridge, {"alpha_grid": (-2, 2, 5)})
    assert "bad-input[window]" in report.passed


def test_a_method_claiming_not_to_use_features_is_checked():
    """uses_features = False lets the toolkit skip building X; check_method catches a method that reads it anyway."""
    from enginebench.api import Method
    from enginebench.methods.naive import NaiveMean

    class ReadsX(Method):
        name = "reads-x"
        family = "data-driven"
        modes = frozenset({"static"})
        uses_features = False

        def fit(self, train, params, rng):
            return train.y.mean(0)

        def predict(self, fitted, data):
            return [fitted + 0.0 * s.X.sum(1, keepdims=True) + (s.X.shape[1] > 0) for s in data.segments]

    with pytest.raises(ConformanceError, match="uses_features = False, but predict gives other predictions"):
        check_method(ReadsX)
    assert "shapes[static]" in check_method(NaiveMean).passed
