"""Methods speak through declared hooks: experiments/ and results/ recognise none by name or class.

``Method.explain`` gives figures their gate bands; a cascade builds its parts through the
registry and passes its downstream's series on; the reference baseline of the tables is
a declared class attribute; the registry imports only the entry point asked for.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from enginebench import registry
from enginebench.datasets.dataset import Dataset
from enginebench.datasets.pools import make_samples
from enginebench.datasets.schema import Schema
from enginebench.errors import MethodError
from enginebench.method import EXPLAIN_WEIGHTS, Method, SegmentPredictions
from enginebench.methods.cascade import Cascade
from enginebench.reports.trajectories import weights_of
from enginebench.results import tables

ROOT = Path(__file__).resolve().parents[2]
NF = {"horizon": 2.0, "stride": 2, "gamma": 0.5, "lambda": 1e-2}


class Blend(Method):
    """A simulating method whose prediction is a fixed blend of two 'experts' (the training mean and zero)."""

    name = "hook-blend"
    family = "data-driven"
    modes = frozenset({"simulation"})
    summary = "test method declaring mixing weights"

    def fit(self, train, params, rng):
        return {"mean": train.y.mean(axis=0), "inputs": tuple(train.input_names)}

    def predict(self, fitted, data):
        return SegmentPredictions([np.tile(0.25 * fitted["mean"], (len(s), 1)) for s in data.segments])

    def explain(self, fitted, data):
        # the weight of the first expert follows the last input: proves the data the cascade passes on
        w = [np.clip(s.U[s.rows, -1:] / 100.0, 0, 1) for s in data.segments]
        return {EXPLAIN_WEIGHTS: [np.hstack([x, 1 - x]) for x in w]}


class Plain(Blend):
    name = "hook-plain"

    def explain(self, fitted, data):
        return super(Blend, self).explain(fitted, data)  # Method's default: nothing declared


@pytest.fixture
def registered(monkeypatch):
    monkeypatch.setattr(registry, "_extra", {**registry._extra, Blend.name: Blend, Plain.name: Plain})


def cascade_data():
    rng = np.random.default_rng(0)
    frames = []
    for s in range(4):
        n = 60
        u1, u2 = 1 + np.cumsum(rng.normal(0, 0.1, n)), rng.uniform(-1, 1, n)
        w = 2 + u1 + 0.3 * u2
        frames.append(pd.DataFrame({"segment": f"s{s}", "time": np.arange(n) * 0.5, "u1": u1, "u2": u2, "w": w,
                                    "y": 1.5 * w + 0.1 * np.cumsum(u2)}))
    schema = Schema.from_roles({"u1": "input", "u2": "input", "w": "internal", "y": "output"})
    sim = make_samples(Dataset("hooks", pd.concat(frames, ignore_index=True), schema, 0.5), ["y"], "simulation")
    cut = sum(len(s) for s in sim.segments[:3])
    return sim.take(np.arange(cut)), sim.take(np.arange(cut, len(sim)))


def test_the_default_explains_nothing_and_figures_then_draw_no_bands(registered):
    train, test = cascade_data()
    m = Plain()
    assert m.explain(m.fit(train, {}, np.random.default_rng(0)), test) == {}
    assert weights_of(m, m.fit(train, {}, np.random.default_rng(0)), test) is None


def test_a_cascade_builds_its_parts_through_the_registry_and_passes_its_downstreams_weights_on(registered):
    train, test = cascade_data()
    c = Cascade(upstream="nfir", downstream="hook-blend", intermediate="w", upstream_params=NF,
                upstream_options={"max_rows": 0})
    assert c.down_cls is Blend and c.up_cls is registry.get("nfir")
    fitted = c.fit(train, {}, np.random.default_rng(0))
    series = c.explain(fitted, test.without_targets())
    w_hat = c.intermediate_predictions(fitted, test.without_targets())["w"]
    assert set(series) == {EXPLAIN_WEIGHTS, "intermediate w"}
    for weights, inter, w, s in zip(series[EXPLAIN_WEIGHTS], series["intermediate w"], w_hat, test.segments):
        assert weights.shape == (len(s), 2) and inter.shape == (len(s), 1)
        np.testing.assert_allclose(inter[:, 0], w)  # the intermediate as fed to the downstream
        np.testing.assert_allclose(weights[:, 0], np.clip(w / 100.0, 0, 1))  # the downstream saw the simulated w
    drawn = weights_of(c, fitted, test.without_targets())
    np.testing.assert_allclose(np.concatenate(drawn).sum(axis=1), 1.0)
    with pytest.raises(MethodError, match="unknown method 'no-such-part'"):
        Cascade(upstream="no-such-part", downstream="hook-blend")


def test_only_a_downstream_declaring_signs_gets_the_seeds_signs(registered):
    c = Cascade(upstream="nfir", downstream="hook-blend", intermediate="w")
    assert "signs" not in c._downstream(("y",), "w").options  # Blend declares no signs option: none imposed


def test_the_tables_reference_baseline_is_declared_by_exactly_one_method():
    declaring = [name for name, cls in registry.available().items() if cls.reference_baseline]
    assert declaring == [tables.BASELINE]
    assert registry.get(tables.BASELINE).family == "baseline"


def test_get_imports_only_the_entry_point_asked_for(monkeypatch):
    loaded = []

    class Recording:
        group = registry.ENTRY_POINT_GROUP

        def __init__(self, name):
            self.name, self.value = name, f"pkg_{name}:Cls"

        def load(self):
            loaded.append(self.name)
            raise SystemExit(3)

    real = registry.entry_points
    monkeypatch.setattr(registry, "entry_points",
                        lambda group: [*real(group=group), Recording("broken-a"), Recording("broken-b")])
    assert registry.get("naive-mean").name == "naive-mean" and loaded == []
    with pytest.raises(MethodError, match="method 'broken-a' cannot be used: .*SystemExit: 3"):
        registry.get("broken-a")
    assert loaded == ["broken-a"]
    with pytest.raises(MethodError, match="unknown method 'nope'; available: .*broken-b"):
        registry.get("nope")
    assert loaded == ["broken-a"]  # listing the names imports nothing


def _imported_modules(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
            out |= {f"{node.module}.{a.name}" for a in node.names}
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
    return out


@pytest.mark.parametrize("folder", ["experiments", "results"])
def test_experiments_and_results_import_no_particular_method(folder):
    for path in sorted((ROOT / folder).glob("*.py")):
        parts = {tuple(m.split(".")[2:3]) for m in _imported_modules(path) if m.startswith("enginebench.methods.")}
        assert parts <= {("base",), ("registry",)}, path  # the contract and the lookup, never a method module


def test_results_reads_no_dataset():
    for path in sorted((ROOT / "results").glob("*.py")):
        assert not {m for m in _imported_modules(path) if m.startswith("enginebench.datasets")}, path
