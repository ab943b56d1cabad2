"""Stored models (results/model_store.py), real-time figures (experiments/keep.py) and FMU export (methods/export)."""

from __future__ import annotations

import importlib.util
import io
import json
import shutil
import subprocess
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.io import write_dataset
from enginebench.datasets.schema import Column, Schema
from enginebench.errors import MethodError, StoreError
from enginebench.experiments.runner import run_experiment
from enginebench.experiments.spec import from_dict
from enginebench.method import Method, SegmentPredictions
from enginebench.registry import register
from enginebench.results.model_store import _Encoder, _decode, encode_model, load_model
from enginebench.results.store import RunStore

NEUTRAL = str(__import__("pathlib").Path(__file__).resolve().parent)
"""A child Python starts here, not in the checkout root, whose ``enginebench/`` source folder would shadow the
installed package (``python -c`` puts its working directory first on sys.path)."""

HAVE_GCC = shutil.which("gcc") is not None
HAVE_FMPY = importlib.util.find_spec("fmpy") is not None
needs_gcc = pytest.mark.skipif(not HAVE_GCC, reason="no C compiler (gcc) on this machine")
needs_fmu = pytest.mark.skipif(not (HAVE_GCC and HAVE_FMPY), reason="FMU export needs gcc and fmpy (extra fmu)")


class Holds(Method):
    """Predicts a constant; its fitted model is a dict holding an object with no stored format (``object()``)
    unless the option ``plain`` is set. It offers no C step."""

    name = "test-holds"
    family = "baseline"
    modes = frozenset({"simulation"})

    @classmethod
    def default_options(cls):
        return {"plain": False}

    def fit(self, train, params, rng):
        return {"c": float(train.y.mean()), "extra": None if self.options["plain"] else object()}

    def predict(self, fitted, data):
        return SegmentPredictions([np.full((len(s), 1), fitted["c"]) for s in data.segments])


register(Holds)


def records(lengths=(600, 400), dt=0.01) -> Dataset:
    """A mildly nonlinear first-order system: records 'est' and 'val'."""
    rng = np.random.default_rng(0)
    frames = []
    for name, n in zip(("est", "val"), lengths):
        u = rng.normal(size=n)
        y = np.zeros(n)
        for i in range(1, n):
            y[i] = 0.7 * y[i - 1] - 0.1 * y[i - 1] ** 3 + 0.5 * np.tanh(u[i - 1])
        frames.append(pd.DataFrame({SEGMENT: name, TIME: np.arange(n) * dt, "u": u, "y": y + 1.0}))
    schema = Schema((Column("u", "input", "V"), Column("y", "output", "V")))
    return Dataset("recs", pd.concat(frames, ignore_index=True), schema, dt, {"provenance": "test"})


METHODS = {"naive-mean": {}, "arx": {"na": [2], "nb": [2]},
           "narx": {"na": [2], "nb": [2], "gamma_grid": [-1, -1, 1], "lambda_grid": [-6, -6, 1]},
           "nfir": {"gamma_grid": [-1, -1, 1], "lambda_grid": [-3, -3, 1]},
           "test-holds": {}}


@pytest.fixture(scope="module")
def kept_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("kept")
    path = write_dataset(records(), tmp / "recs.parquet")
    spec = from_dict({"name": "keep", "dataset": str(path), "targets": ["y"], "mode": "simulation", "repetitions": 1,
                      "train_size": 0, "init_samples": 10, "split": {"kind": "records", "train": ["est"], "test": ["val"]},
                      "selection": {"kind": "kfold", "folds": 2}, "store": {"models": True}, "methods": METHODS},
                     origin="test")
    return run_experiment(spec, RunStore(tmp / "runs"), workers=1).run


def model_file(run, method: str) -> Path:
    (path,) = [p for p in (run.path / "models").glob("*.npz") if f"__{method}__" in p.name]
    return path


# -- the state tree ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Inner:
    a: np.ndarray
    k: int


@dataclass(frozen=True)
class Outer:
    inner: tuple
    table: dict
    x: float
    s: np.float32


def test_state_tree_round_trip_is_bit_for_bit():
    obj = Outer(inner=(Inner(np.array([1.0, np.nextafter(1.0, 2.0)]), 3), None), table={"n": np.arange(3), "f": np.nan},
                x=0.1 + 0.2, s=np.float32(1.5))
    enc = _Encoder(("enginebench.", __name__))
    tree = json.loads(json.dumps(enc.encode(obj)))
    back = _decode(tree, enc.arrays, ("enginebench.", __name__))
    assert type(back) is Outer and type(back.inner[0]) is Inner
    assert back.inner[0].a.tobytes() == obj.inner[0].a.tobytes() and back.inner[0].k == 3 and back.inner[1] is None
    assert back.x == obj.x and np.isnan(back.table["f"]) and back.table["n"].tolist() == [0, 1, 2]
    assert back.s.dtype == np.float32 and back.s == np.float32(1.5)


def test_a_dataclass_outside_the_allowed_packages_is_refused_on_load():
    enc = _Encoder(("enginebench.", __name__))
    tree = enc.encode(Inner(np.zeros(1), 1))
    with pytest.raises(StoreError, match="outside the packages a stored model may name"):
        _decode(tree, enc.arrays, ("enginebench.",))


def test_an_object_without_a_safe_format_is_not_storable():
    method = Holds()
    with pytest.raises(MethodError, match=r"method 'test-holds': its fitted model is not storable \(model.extra is a "
                                          r"builtins:object, which has no safe stored format here: not storable\)"):
        encode_model(method, {"c": 1.0, "extra": object()}, data=None, params={}, job={})


# -- a run that keeps its models -----------------------------------------------------------------
@pytest.mark.parametrize("method", ["naive-mean", "arx", "narx", "nfir"])
def test_a_stored_model_predicts_the_runs_test_predictions_bit_for_bit(kept_run, method):
    model = load_model(model_file(kept_run, method))
    assert model.meta["format"] == "enginebench-model" and model.meta["versions"]["numpy"] == np.__version__
    assert model.check() == 0.0
    (seg,) = model.check_data
    again = model.simulate(seg["U"], seg["y_init"])  # the public call: inputs and the init window only
    assert again.tobytes() == seg["prediction"].tobytes()


def test_the_job_file_records_the_model_files_sha256(kept_run):
    import hashlib

    path = model_file(kept_run, "arx")
    meta = kept_run.job_meta(path.name[:-4])
    assert meta["model_file"]["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()


def test_a_model_that_cannot_be_stored_leaves_the_job_ok_with_a_warning(kept_run):
    assert not [p for p in (kept_run.path / "models").glob("*test-holds*")]
    meta = kept_run.job_meta([p.stem for p in kept_run.job_files() if "__test-holds__" in p.stem][0])
    assert meta["status"] == "ok"
    assert any("test-holds: model not stored (method 'test-holds': its fitted model is not storable" in w
               for w in meta["warnings"])


def _rewrite(src: Path, dst: Path, change) -> None:
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for info in zin.infolist():
            zout.writestr(info.filename, change(info.filename, zin.read(info.filename)))


def test_a_tampered_stored_model_is_refused(kept_run, tmp_path):
    src = model_file(kept_run, "arx")

    def array(name, data):  # one coefficient changed, a valid .npy and zip around it
        if name != "a0.npy":
            return data
        a = np.load(io.BytesIO(data))
        a.flat[0] += 1e-12
        buf = io.BytesIO()
        np.save(buf, a)
        return buf.getvalue()

    _rewrite(src, tmp_path / "a.npz", array)
    with pytest.raises(StoreError, match=r"does not match its SHA-256 checksum \(a changed byte\); it is refused"):
        load_model(tmp_path / "a.npz")
    _rewrite(src, tmp_path / "b.npz", lambda n, d: d.replace(b'"params"', b'"paramz"') if n == "model.json" else d)
    with pytest.raises(StoreError, match="does not match its SHA-256 checksum"):
        load_model(tmp_path / "b.npz")
    raw = bytearray(src.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    (tmp_path / "c.npz").write_bytes(bytes(raw))
    with pytest.raises(StoreError, match="refused"):
        load_model(tmp_path / "c.npz")
    # inside the run folder, the job file's record is checked too: a re-signed file is still refused
    from enginebench.results import model_store

    meta, arrays = model_store.read_model_file(src)
    arrays["a0"] = arrays["a0"] + 1.0
    meta["sha256"] = model_store.content_sha256(meta, arrays)
    fake = src.parent / "fake.npz"
    with zipfile.ZipFile(fake, "w") as zf:
        zf.writestr("model.json", json.dumps(meta))
        for name, a in arrays.items():
            zf.writestr(f"{name}.npy", model_store._npy(a))
    forged = src.with_name(src.name)
    backup = src.read_bytes()
    try:
        fake.replace(forged)
        with pytest.raises(StoreError, match="does not match the SHA-256 its run's job file records"):
            load_model(forged)
    finally:
        forged.write_bytes(backup)


def test_a_stored_model_opens_in_a_fresh_process_without_training(kept_run):
    path = model_file(kept_run, "narx")
    code = f"""
import sys
from enginebench import registry
cls = registry.get("narx")
def refuse(*a, **k):
    raise SystemExit("training code ran")
cls.fit = cls.fit_grid = cls.predict_grid = refuse
from enginebench.api import load_model
m = load_model({str(path)!r})
print(repr(m.check()))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=NEUTRAL)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "0.0"


def test_realtime_figures_are_recorded_for_every_simulation_job(kept_run):
    metrics = kept_run.metrics()
    for method in ("naive-mean", "arx", "narx", "nfir", "test-holds"):
        rows = metrics[(metrics["method"] == method) & metrics["metric"].str.startswith("rt_")]
        assert sorted(rows["metric"]) == ["rt_factor", "rt_median_us", "rt_p99_us", "rt_worst_us"]
        meta = kept_run.job_meta([p.stem for p in kept_run.job_files() if f"__{method}__" in p.stem][0])
        figures = meta["realtime"]
        print(method, figures)  # reported, never asserted: timings depend on the machine
        assert figures["steps"] == 400 and figures["dt_s"] == 0.01
        expected = "c-step" if method != "test-holds" and HAVE_GCC else "python-batched"
        assert figures["source"] == expected


def test_runs_show_and_table_print_the_realtime_figures(kept_run):
    from click.testing import CliRunner

    from enginebench.cli.main import cli

    out = CliRunner().invoke(cli, ["runs", "show", str(kept_run.path)])
    assert out.exit_code == 0, out.output
    assert "one model step over the test part" in out.output and "dt / worst" in out.output
    out = CliRunner().invoke(cli, ["table", str(kept_run.path), "--metrics", "rt", "--format", "csv"])
    assert out.exit_code == 0, out.output
    assert "rt_worst_us" in out.output


def test_keep_models_is_not_part_of_the_config_hash():
    base = {"dataset": "x", "targets": ["y"], "methods": ["arx"]}
    assert from_dict({**base, "store": {"models": True}}).config_hash() == from_dict(base).config_hash()
    with pytest.raises(Exception, match=r"\[store\] knows the key models \(true/false\), not model"):
        from_dict({**base, "store": {"model": True}})


# -- FMU export ----------------------------------------------------------------------------------
@needs_fmu
@pytest.mark.parametrize("method", ["naive-mean", "arx", "narx", "nfir"])
def test_each_exportable_methods_fmu_reproduces_the_runs_predictions(kept_run, method, tmp_path):
    from enginebench.reports.fmu_export import export_fmu, find_model

    path = find_model(kept_run.path, kept_run.id, method, None, None)
    result = export_fmu(path, tmp_path / f"{method}.fmu", timing=True, run_id=kept_run.id)
    print(method, result.max_abs, result.max_rel, result.timing)
    assert result.steps == 390 and result.ok and result.max_rel <= 1e-9
    if method in ("arx", "naive-mean"):
        assert result.max_abs == 0.0  # the same arithmetic in the same order
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(result.path)) == []


@needs_fmu
def test_export_cli_prints_the_difference_and_refuses_a_method_without_a_c_step(kept_run, tmp_path):
    from click.testing import CliRunner

    from enginebench.cli.main import cli

    out = CliRunner().invoke(cli, ["export", str(kept_run.path), "--method", "arx", "--fmu", str(tmp_path / "a.fmu")])
    assert out.exit_code == 0, out.output
    assert "checked with fmpy over 390 test steps against the run's predictions: largest difference 0 absolute" \
        in out.output
    holds = CliRunner().invoke(cli, ["export", str(kept_run.path), "--method", "test-holds", "--fmu",
                                     str(tmp_path / "h.fmu")])
    assert holds.exit_code == 2
    assert f"run {kept_run.id} stored no model of method 'test-holds'" in holds.output
    missing = CliRunner().invoke(cli, ["export", str(kept_run.path), "--fmu", str(tmp_path / "x.fmu")])
    assert missing.exit_code == 2 and "--fmu needs --method METHOD" in missing.output


@needs_gcc
def test_a_method_without_a_c_step_cannot_be_exported_in_one_line():
    from enginebench.c_model import check_exportable

    with pytest.raises(MethodError, match=r"^method 'test-holds' cannot be exported: it offers no C step"):
        check_exportable(Holds(plain=True), {"c": 1.0, "extra": None}, ("y",))


STEP_SIZES = """
import sys
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave


md = read_model_description(sys.argv[1])
print("stepSize", md.defaultExperiment.stepSize, flush=True)
fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(sys.argv[1]), modelIdentifier=md.coSimulation.modelIdentifier,
                instanceName="x")
fmu.instantiate()
fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode()
fmu.exitInitializationMode()
for h in (0.015, 0.02):
    try:
        fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=h)
        print(h, "ok", flush=True)
    except Exception as exc:
        print(h, "refused:", exc, flush=True)
fmu.terminate()
fmu.freeInstance()
"""


@needs_fmu
def test_an_fmu_refuses_a_step_that_is_not_a_multiple_of_dt(kept_run, tmp_path):
    from enginebench.reports.fmu_export import export_fmu, find_model

    result = export_fmu(find_model(kept_run.path, kept_run.id, "arx", None, None), tmp_path / "arx.fmu")
    # fmpy runs the FMU in a child process: native code that crashed would end that process, never the suite
    out = subprocess.run([sys.executable, "-c", STEP_SIZES, str(result.path)], capture_output=True, text=True, cwd=NEUTRAL,
                         timeout=120)
    assert out.returncode == 0, f"exit {out.returncode}: {out.stdout}{out.stderr[-2000:]}"
    lines = out.stdout.splitlines()
    assert lines[0] == "stepSize 0.01"
    # fmpy's default logger prints the FMU's own message, then fmpy raises on the error status
    assert "[ERROR] fmi2DoStep: the step size must be a whole multiple of the model's sample period" in lines
    assert "0.015 refused: fmi2DoStep failed with status 3 (error)." in lines
    assert lines[-1] == "0.02 ok"  # two whole periods, inputs held


def test_realtime_figures_come_from_the_methods_step_times_hook_alone():
    from types import SimpleNamespace

    from enginebench.experiments.keep import realtime_figures

    test = SimpleNamespace(dt=0.01, segments=[SimpleNamespace(t=np.arange(3)), SimpleNamespace(t=np.arange(1))])

    class Own:
        def step_times(self, fitted, data):
            return "own-step", np.array([1e-6, 2e-6, 3e-6, 4e-6])

    class Cannot:
        def step_times(self, fitted, data):
            raise MethodError("method 'x': no C compiler found (gcc or $CC); install gcc to export or time a model")

    own = realtime_figures(Own(), None, test, 1.0)
    assert own["source"] == "own-step" and own["steps"] == 4 and own["worst_us"] == pytest.approx(4.0)
    assert own["rt_factor"] == pytest.approx(0.01 / 4e-6)
    for method, why in ((Holds(), "the method times no step of its own"), (Cannot(), "no C compiler found")):
        fallback = realtime_figures(method, None, test, 0.002)
        assert fallback["source"] == "python-batched" and fallback["median_us"] == pytest.approx(500.0)
        assert fallback["note"].startswith("the test part's prediction time over its 4 steps (") and why in \
            fallback["note"]


def test_a_failed_fmu_check_leaves_an_fmu_already_at_the_output_path(kept_run, tmp_path, monkeypatch):
    """The FMU is built beside the output and moved over it only once it agrees with the run: when the simulated
    FMU disagrees (here made to, by 1.0 on every output), the file already at the output path is left as it was and
    the unchecked build is reported."""
    pytest.importorskip("fmpy", reason="fmpy is not installed (pip install enginebench[fmu])")
    from enginebench.reports import fmu_export
    from enginebench.reports.fmu_export import export_fmu, find_model

    real = fmu_export.simulate_fmu
    monkeypatch.setattr(fmu_export, "simulate_fmu", lambda *a, **k: (lambda Y, t: (Y + 1.0, t))(*real(*a, **k)))

    if shutil.which("gcc") is None and shutil.which("cc") is None:
        pytest.skip("no C compiler")
    run = kept_run
    model = find_model(run.path, run.id, "arx", None, None)
    out = tmp_path / "arx.fmu"
    out.write_bytes(b"an earlier export")
    result = export_fmu(model, out, run_id=run.id)
    assert not result.ok and result.path != out and result.path.exists()
    assert out.read_bytes() == b"an earlier export"
