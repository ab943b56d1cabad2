"""An FMU as a dataset's physical model: a first-order thermal FMU built here from C, checked against its analytic solution.

The FMU (tests/data/fmu/thermal_fmi2.c, compiled with the C compiler and fmpy's FMI
headers, once per session) models dT/dt = (K u - (T - T_amb)) / tau with T(0) = T_amb,
so for a constant input T(t) = T_amb + K u (1 - exp(-t / tau)).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from click.testing import CliRunner

NEUTRAL = str(__import__("pathlib").Path(__file__).resolve().parent)
"""A child Python starts here, not in the checkout root, whose ``enginebench/`` source folder would shadow the
installed package (``python -c`` puts its working directory first on sys.path)."""

fmpy = pytest.importorskip("fmpy", reason="fmpy is not installed (pip install enginebench[fmu])")

from enginebench.datasets.fmu import FMUPhysicalModel, open_fmu  # noqa: E402
from enginebench.datasets.fmu_spec import parse_physical_model  # noqa: E402
from enginebench.datasets.importer import import_table  # noqa: E402
from enginebench.errors import DataError, SpecError  # noqa: E402

SOURCE = Path(__file__).parent.parent / "data" / "fmu" / "thermal_fmi2.c"
SOURCE3 = SOURCE.with_name("thermal_fmi3.c")
MODEL_DESCRIPTION = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName="thermal" guid="{GUID}" numberOfEventIndicators="0">
  <ModelExchange modelIdentifier="thermal"/>
  <CoSimulation modelIdentifier="thermal" canHandleVariableCommunicationStepSize="true"/>
  <ModelVariables>
    <ScalarVariable name="T" valueReference="0" causality="output" variability="continuous" initial="calculated"><Real/></ScalarVariable>
    <ScalarVariable name="der(T)" valueReference="1" causality="local" variability="continuous" initial="calculated"><Real derivative="1"/></ScalarVariable>
    <ScalarVariable name="u" valueReference="2" causality="input" variability="continuous"><Real start="0"/></ScalarVariable>
    <ScalarVariable name="K" valueReference="3" causality="parameter" variability="fixed" initial="exact"><Real start="1"/></ScalarVariable>
    <ScalarVariable name="tau" valueReference="4" causality="parameter" variability="fixed" initial="exact"><Real start="10" min="0.01" max="1000"/></ScalarVariable>
    <ScalarVariable name="T_amb" valueReference="5" causality="parameter" variability="fixed" initial="exact"><Real start="20"/></ScalarVariable>
    <ScalarVariable name="fail_time" valueReference="6" causality="parameter" variability="fixed" initial="exact"><Real start="-1"/></ScalarVariable>
  </ModelVariables>
  <ModelStructure>
    <Outputs><Unknown index="1"/></Outputs>
    <Derivatives><Unknown index="2"/></Derivatives>
    <InitialUnknowns><Unknown index="1"/><Unknown index="2"/></InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""
MODEL_DESCRIPTION3 = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="3.0" modelName="thermal" instantiationToken="{8c4e810f-0000-4000-8000-000000000003}">
  <ModelExchange modelIdentifier="thermal"/>
  <CoSimulation modelIdentifier="thermal" canHandleVariableCommunicationStepSize="true"/>
  <ModelVariables>
    <Float64 name="time" valueReference="7" causality="independent" variability="continuous"/>
    <Float64 name="T" valueReference="0" causality="output" variability="continuous" initial="calculated"/>
    <Float64 name="der(T)" valueReference="1" causality="local" variability="continuous" initial="calculated" derivative="0"/>
    <Float64 name="u" valueReference="2" causality="input" variability="continuous" start="0"/>
    <Float64 name="K" valueReference="3" causality="parameter" variability="fixed" start="1"/>
    <Float64 name="tau" valueReference="4" causality="parameter" variability="fixed" start="10" min="0.01" max="1000"/>
    <Float64 name="T_amb" valueReference="5" causality="parameter" variability="fixed" start="20"/>
    <Float64 name="fail_time" valueReference="6" causality="parameter" variability="fixed" start="-1"/>
  </ModelVariables>
  <ModelStructure>
    <Output valueReference="0"/>
    <ContinuousStateDerivative valueReference="1"/>
    <InitialUnknown valueReference="0"/>
    <InitialUnknown valueReference="1"/>
  </ModelStructure>
</fmiModelDescription>
"""
TRUE = {"tau": 4.0, "K": 2.5, "T_amb": 20.0}


def analytic(t: np.ndarray, u: float, tau: float, K: float, T_amb: float = 20.0) -> np.ndarray:
    """Step response from T(0) = T_amb (t from the segment's start)."""
    return T_amb + K * u * (1.0 - np.exp(-(t - t[0]) / tau))


def write_fmu(path: Path, library: Path | None, description: str = MODEL_DESCRIPTION,
              platform: str | None = None) -> Path:
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("modelDescription.xml", description)
        if library is not None:
            ext = ".dll" if platform and platform.startswith("win") else fmpy.sharedLibraryExtension
            zf.write(library, f"binaries/{platform or fmpy.platform}/thermal{ext}")
    return path


def compile_library(source: Path, out: Path) -> Path:
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None or fmpy.platform != "linux64":
        pytest.skip("the test FMU is compiled with gcc/cc on linux64")
    headers = Path(fmpy.__file__).parent / "c-code"
    subprocess.run([cc, "-shared", "-fPIC", "-O2", f"-I{headers}", str(source), "-o", str(out), "-lm"], check=True)
    return out


@pytest.fixture(scope="session")
def library(tmp_path_factory) -> Path:
    return compile_library(SOURCE, tmp_path_factory.mktemp("fmu-build") / f"thermal{fmpy.sharedLibraryExtension}")


@pytest.fixture(scope="session")
def thermal_fmu3(tmp_path_factory) -> Path:
    """The FMI 3.0 build: its binary lies under the platform tuple (x86_64-linux)."""
    folder = tmp_path_factory.mktemp("fmu3")
    lib = compile_library(SOURCE3, folder / f"thermal{fmpy.sharedLibraryExtension}")
    with zipfile.ZipFile(folder / "thermal3.fmu", "w") as zf:
        zf.writestr("modelDescription.xml", MODEL_DESCRIPTION3)
        zf.write(lib, f"binaries/{fmpy.platform_tuple}/thermal{fmpy.sharedLibraryExtension}")
    return folder / "thermal3.fmu"


@pytest.fixture(scope="session")
def thermal_fmu(library, tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("fmu")
    return write_fmu(folder / "thermal.fmu", library, MODEL_DESCRIPTION.replace("GUID", "8c4e810f-0000-4000-8000-000000000001"))


def config(fmu: Path, **changes) -> dict:
    raw = {"fmu": str(fmu), "inputs": {"power": "u"}, "outputs": {"temp": "T"},
           "parameters": {"tau": 5.0, "K": 3.0}}
    raw.update(changes)
    return {**parse_physical_model(raw, fmu.parent / "spec.toml"), "dt": 1.0}


def thermal_records(folder: Path, n: int = 60, levels=(1.0, 2.0, -1.5)) -> Path:
    """One CSV record per constant input level, temperature from the analytic solution with TRUE."""
    for k, u in enumerate(levels):
        t = 100.0 * k + np.arange(n, dtype=float)
        T = analytic(t, u, TRUE["tau"], TRUE["K"], TRUE["T_amb"])
        pd.DataFrame({"t": t, "power": u, "temp": T}).to_csv(folder / f"r{k}.csv", index=False)
    return folder


def write_spec(folder: Path, fmu: str, physical_model: str) -> Path:
    thermal_records(folder)
    spec = folder / "thermal.toml"
    spec.write_text(textwrap.dedent(f"""\
        name = "thermal"
        dt = 1.0
        time = "t"
        files = ["r0.csv", "r1.csv", "r2.csv"]
        [columns]
        power = {{ role = "input", unit = "kW" }}
        temp = {{ role = "output", unit = "degC" }}
        [physical_model]
        fmu = "{fmu}"
        """) + textwrap.dedent(physical_model))
    return spec


PM_TABLE = """\
    inputs = { power = "u" }
    outputs = { temp = "T" }
    parameters = { tau = 6.0, K = 2.0 }
    """


# -- simulation ------------------------------------------------------------------------------------
@pytest.mark.parametrize("version", ["thermal_fmu", "thermal_fmu3"])
@pytest.mark.parametrize("fmi_type, tol", [("CoSimulation", 1e-10), ("ModelExchange", 1e-5)])
def test_simulation_reproduces_the_analytic_step_response(request, version, fmi_type, tol):
    pm = FMUPhysicalModel(config(request.getfixturevalue(version), fmi_type=fmi_type))
    t = 1000.0 + np.arange(50, dtype=float)  # the segment's first stamp is the FMU's t = 0
    out = pm.simulate(pm.parameters, {"time": t, "power": np.full(50, 2.0)}, 1.0)
    np.testing.assert_allclose(out["temp"], analytic(t, 2.0, 5.0, 3.0), atol=tol * 10, rtol=tol)
    again = pm.simulate({"tau": 2.0, "K": 1.0}, {"time": t, "power": np.full(50, 2.0)}, 1.0)  # the instance is reset
    np.testing.assert_allclose(again["temp"], analytic(t, 2.0, 2.0, 1.0), atol=tol * 10, rtol=tol)


def test_both_interfaces_present_co_simulation_is_taken_and_model_exchange_chosen(thermal_fmu):
    assert open_fmu(thermal_fmu).fmi_type == "CoSimulation"
    assert open_fmu(thermal_fmu, "ModelExchange").fmi_type == "ModelExchange"


def test_a_model_pickles_without_its_instance_and_simulates_in_the_copy(thermal_fmu):
    import pickle

    pm = FMUPhysicalModel(config(thermal_fmu))
    t = np.arange(10, dtype=float)
    first = pm.simulate(pm.parameters, {"time": t, "power": np.ones(10)}, 1.0)
    copy = pickle.loads(pickle.dumps(pm))
    np.testing.assert_array_equal(copy.simulate(pm.parameters, {"time": t, "power": np.ones(10)}, 1.0)["temp"],
                                  first["temp"])


# -- calibration ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("version", ["thermal_fmu", "thermal_fmu3"])
@pytest.mark.parametrize("fmi_type, rtol", [("CoSimulation", 1e-7), ("ModelExchange", 1e-3)])
def test_calibrate_recovers_tau_and_K(request, version, fmi_type, rtol):
    pm = FMUPhysicalModel(config(request.getfixturevalue(version), fmi_type=fmi_type, calibrate=["tau", "K"],
                                 parameters={"tau": 10.0, "K": 1.0}))
    segs = []
    for u in (1.0, -2.0):
        t = np.arange(40, dtype=float)
        segs.append({"time": t, "power": np.full(40, u), "temp": analytic(t, u, TRUE["tau"], TRUE["K"])})
    params = pm.calibrate(segs)
    assert params["tau"] == pytest.approx(TRUE["tau"], rel=rtol)
    assert params["K"] == pytest.approx(TRUE["K"], rel=rtol)


def test_no_calibrate_list_keeps_the_spec_parameters(thermal_fmu):
    pm = FMUPhysicalModel(config(thermal_fmu))
    assert pm.calibrate([]) == {"tau": 5.0, "K": 3.0}


# -- import and the runner ---------------------------------------------------------------------------
def test_import_stores_the_fmu_absolute_with_its_sha256(thermal_fmu, tmp_path):
    shutil.copy(thermal_fmu, tmp_path / "model.fmu")
    ds = import_table(write_spec(tmp_path, "model.fmu", PM_TABLE))
    meta = ds.meta["fmu"]
    assert ds.meta["physical_model"] == "fmu"
    assert meta["fmu"] == str((tmp_path / "model.fmu").resolve())
    assert meta["sha256"] == __import__("hashlib").sha256((tmp_path / "model.fmu").read_bytes()).hexdigest()
    assert meta["fmi_type"] == "CoSimulation" and meta["dt"] == 1.0


def test_a_changed_fmu_after_import_is_an_error(thermal_fmu, library, tmp_path):
    from enginebench.physical import get_physical_model

    shutil.copy(thermal_fmu, tmp_path / "model.fmu")
    ds = import_table(write_spec(tmp_path, "model.fmu", PM_TABLE))
    assert isinstance(get_physical_model("fmu", ds.meta), FMUPhysicalModel)
    write_fmu(tmp_path / "model.fmu", library, MODEL_DESCRIPTION.replace("GUID", "8c4e810f-0000-4000-8000-00000000000f"))
    old, new = ds.meta["fmu"]["sha256"], __import__("hashlib").sha256((tmp_path / "model.fmu").read_bytes()).hexdigest()
    with pytest.raises(DataError) as err:
        get_physical_model("fmu", ds.meta)
    assert str(err.value) == (f"{ds.meta['fmu']['fmu']}: the FMU file changed since the dataset was imported (sha256 "
                              f"{old[:12]}... then, {new[:12]}... now); re-import the dataset from its spec, or "
                              "restore the FMU")


class AnalyticThermal:
    """The thermal model's closed form for inputs constant over each segment (the reference for the FMU path)."""

    name = "analytic-thermal"
    inputs = ("power",)
    outputs = ("temp",)

    def __init__(self, params):
        self.params = params

    def calibrate(self, segments):
        return dict(self.params)

    def simulate(self, params, segment, dt):
        t = np.asarray(segment["time"], dtype=float)
        return {"temp": analytic(t, float(segment["power"][0]), params["tau"], params["K"])}


def test_pm_through_the_runner_scores_as_the_analytic_model(thermal_fmu, tmp_path, monkeypatch):
    from enginebench.experiments import runner
    from enginebench.experiments.spec import from_dict
    from enginebench.results.realtime import RT_METRICS
    from enginebench.results.store import RunStore

    shutil.copy(thermal_fmu, tmp_path / "model.fmu")
    spec_path = write_spec(tmp_path, "model.fmu", PM_TABLE)
    raw = {"name": "fmu-exp", "dataset": str(spec_path), "targets": ["temp"], "mode": "simulation", "repetitions": 1,
           "train_size": 0, "split": {"kind": "records", "train": ["r0", "r1"], "test": ["r2"]},
           "selection": {"kind": "none"}, "methods": {"pm": {}}}
    fmu_run = runner.run_experiment(from_dict(raw, origin="test"), RunStore(tmp_path / "runs"), workers=1)
    assert fmu_run.n_failed == 0
    monkeypatch.setattr(runner, "physical_model_for", lambda ds: AnalyticThermal({"tau": 6.0, "K": 2.0}))
    ref_run = runner.run_experiment(from_dict(raw, origin="test"), RunStore(tmp_path / "runs2"), workers=1)

    def scores(result):
        m = result.run.metrics()
        # timings (time_*, and the real-time step figures rt_* of experiments/keep.py) are the machine's, not scores
        m = m[~m["metric"].str.startswith("time_") & ~m["metric"].isin(RT_METRICS)].sort_values(["split", "metric"])
        return m.set_index(["split", "metric"])["value"]

    got, want = scores(fmu_run), scores(ref_run)
    assert list(got.index) == list(want.index)
    assert want.loc[("test", "rmse")] > 0.1  # the spec's parameters are not the data's: a real error to match
    np.testing.assert_allclose(got.to_numpy(), want.to_numpy(), rtol=1e-9, atol=1e-9)


def test_a_failure_mid_segment_fails_the_pm_job_naming_segment_and_time(thermal_fmu, tmp_path):
    from enginebench.experiments import runner
    from enginebench.experiments.spec import from_dict
    from enginebench.results.store import RunStore

    shutil.copy(thermal_fmu, tmp_path / "model.fmu")
    spec_path = write_spec(tmp_path, "model.fmu", PM_TABLE.replace("K = 2.0", "K = 2.0, fail_time = 30.5"))
    raw = {"name": "fmu-fail", "dataset": str(spec_path), "targets": ["temp"], "mode": "simulation",
           "repetitions": 1, "train_size": 0, "split": {"kind": "records", "train": ["r0", "r1"], "test": ["r2"]},
           "selection": {"kind": "none"}, "methods": {"pm": {}}}
    result = runner.run_experiment(from_dict(raw, origin="test"), RunStore(tmp_path / "runs"), workers=1)
    assert result.n_failed == 1
    reason = result.run.job_meta("temp__w0__records__pm__r000")["reason"]
    assert reason == (f"SimulationFailed: {tmp_path / 'model.fmu'}: the FMU failed after t = 230 s in the segment "
                      "spanning t = 200 .. 259 s (thermal: failure injected); check the inputs there and the parameters")


# -- the command line -----------------------------------------------------------------------------------
def test_calibrate_pm_on_training_rows_and_on_fat_points(thermal_fmu, tmp_path):
    from enginebench.cli.main import cli as main

    shutil.copy(thermal_fmu, tmp_path / "model.fmu")
    spec_path = write_spec(tmp_path, "model.fmu", PM_TABLE + 'calibrate = { tau = [0.5, 50.0], K = [0.1, 10.0] }\n')
    res = CliRunner().invoke(main, ["calibrate", "pm", "--dataset", str(spec_path), "--on", "train"])
    assert res.exit_code == 0, res.output
    lines = {line.split()[0]: line.split() for line in res.output.splitlines() if line.strip()}
    assert float(lines["tau"][1]) == 6.0 and float(lines["tau"][2]) == pytest.approx(TRUE["tau"], rel=1e-5)
    assert float(lines["K"][2]) == pytest.approx(TRUE["K"], rel=1e-5)
    assert "every segment (3 segment(s), 180 rows)" in res.output

    u = np.array([0.5, 1.0, 2.0])
    pd.DataFrame({"power": u, "temp": TRUE["T_amb"] + 1.75 * u}).to_csv(tmp_path / "fat.csv", index=False)
    res = CliRunner().invoke(main, ["calibrate", "pm", "--dataset", str(spec_path), "--fat", str(tmp_path / "fat.csv"),
                                    "--settle", "200", "-o", str(tmp_path / "params.json")])
    assert res.exit_code == 0, res.output
    import json

    fitted = json.loads((tmp_path / "params.json").read_text())["params"]
    assert fitted["K"] == pytest.approx(1.75, rel=1e-6)  # steady state T_amb + K u fixes K; tau is not identified


# -- errors: one line each ---------------------------------------------------------------------------------
def test_errors_are_one_line_each(thermal_fmu, library, tmp_path):
    missing = tmp_path / "nothing.fmu"
    with pytest.raises(DataError, match=r"nothing.fmu: FMU file not found; give the path of an .fmu file"):
        open_fmu(missing)
    (tmp_path / "junk.fmu").write_bytes(b"not a zip")
    with pytest.raises(DataError) as err:
        open_fmu(tmp_path / "junk.fmu")
    assert str(err.value) == f"{tmp_path / 'junk.fmu'}: not an FMU (not a zip archive); export the model as an FMU again"
    with zipfile.ZipFile(tmp_path / "empty.fmu", "w") as zf:
        zf.writestr("readme.txt", "x")
    with pytest.raises(DataError, match=r"empty.fmu: not an FMU \(no modelDescription.xml inside\)"):
        open_fmu(tmp_path / "empty.fmu")
    write_fmu(tmp_path / "bad.fmu", library, "<fmiModelDescription fmiVersion='2.0'")
    with pytest.raises(DataError, match=r"bad.fmu: modelDescription.xml cannot be read \(.*\); the FMU is damaged: "
                                        "export it again$"):
        open_fmu(tmp_path / "bad.fmu")
    write_fmu(tmp_path / "win.fmu", library, MODEL_DESCRIPTION.replace("GUID", "x"), platform="win64")
    with pytest.raises(DataError) as err:
        open_fmu(tmp_path / "win.fmu")
    assert str(err.value) == (f"{tmp_path / 'win.fmu'}: no binary for this platform ({fmpy.platform}); the FMU has "
                              f"binaries for win64; export it for {fmpy.platform}")
    with pytest.raises(DataError) as err:
        FMUPhysicalModel(config(thermal_fmu, parameters={"tua": 5.0})).fmu
    assert str(err.value) == f"{thermal_fmu}: the FMU has no variable 'tua' (physical_model.parameters); close names: tau, u, T_amb"
    with pytest.raises(DataError) as err:
        FMUPhysicalModel(config(thermal_fmu, inputs={"power": "T"})).fmu
    assert "variable 'T' (physical_model.inputs, column 'power') is not an input of the FMU" in str(err.value)
    for e in (err,):
        assert "\n" not in str(e.value)


def test_unknown_variable_and_column_at_import(thermal_fmu, tmp_path):
    shutil.copy(thermal_fmu, tmp_path / "model.fmu")
    spec = write_spec(tmp_path, "model.fmu", PM_TABLE.replace('outputs = { temp = "T" }', 'outputs = { temp = "Temp" }'))
    with pytest.raises(DataError) as err:
        import_table(spec)
    assert str(err.value) == (f"{(tmp_path / 'model.fmu').resolve()}: the FMU has no variable 'Temp' "
                              "(physical_model.outputs, column 'temp'); close names: T_amb, T")
    spec = write_spec(tmp_path, "model.fmu", PM_TABLE.replace("inputs = { power", "inputs = { pwr"))
    with pytest.raises(DataError, match=r"thermal.toml: \[physical_model\] inputs: 'pwr' is not a column declared in "
                                        r"\[columns\]; did you mean 'power'\?"):
        import_table(spec)


def test_spec_table_mistakes_are_spec_errors(tmp_path):
    origin = tmp_path / "s.toml"
    with pytest.raises(SpecError, match=r"s.toml: \[physical_model\]: unknown key 'input' \(did you mean 'inputs'\?\)"):
        parse_physical_model({"fmu": "a.fmu", "input": {}, "outputs": {"y": "y"}}, origin)
    with pytest.raises(SpecError, match=r"\[physical_model\] calibrate: 'tau' has lower bound 5 >= upper bound 1"):
        parse_physical_model({"fmu": "a.fmu", "outputs": {"y": "y"}, "calibrate": {"tau": [5, 1]}}, origin)
    with pytest.raises(SpecError, match=r"fmi_type must be one of CoSimulation, ModelExchange, got 'CS'"):
        parse_physical_model({"fmu": "a.fmu", "outputs": {"y": "y"}, "fmi_type": "CS"}, origin)
    assert parse_physical_model({"fmu": "sub/a.fmu", "outputs": {"y": "y"}}, origin)["fmu"] == str(
        (tmp_path / "sub" / "a.fmu").resolve())


def test_fmpy_missing_is_one_line(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "fmpy", None)
    with pytest.raises(DataError) as err:
        open_fmu(tmp_path / "a.fmu")
    assert str(err.value) == "FMU physical models need fmpy, which is not installed: pip install enginebench[fmu]"


def test_cli_prints_an_error_line_not_a_traceback(tmp_path):
    from enginebench.cli.main import cli as main

    (tmp_path / "model.fmu").write_bytes(b"garbage")
    spec = write_spec(tmp_path, "model.fmu", PM_TABLE)
    res = CliRunner().invoke(main, ["datasets", "show", str(spec)])
    assert res.exit_code == 2
    assert res.output.strip() == f"error: {(tmp_path / 'model.fmu').resolve()}: not an FMU (not a zip archive); " \
                                 "export the model as an FMU again"


@pytest.mark.parametrize("version", ["thermal_fmu", "thermal_fmu3"])
@pytest.mark.parametrize("fmi_type", ["CoSimulation", "ModelExchange"])
def test_a_failing_fmu_names_the_time_and_the_segment_and_recovers(request, version, fmi_type):
    from enginebench.datasets.fmu import SimulationFailed

    path = request.getfixturevalue(version)
    pm = FMUPhysicalModel(config(path, fmi_type=fmi_type))
    t = 50.0 + np.arange(20, dtype=float)
    seg = {"time": t, "power": np.ones(20)}
    with pytest.raises(SimulationFailed) as err:
        pm.simulate({**pm.parameters, "fail_time": 7.5}, seg, 1.0)
    after = 57 if fmi_type == "CoSimulation" else None  # co-simulation fails in the step from 7 to 8 s
    message = str(err.value)
    assert message.startswith(f"{path}: the FMU failed after t = ")
    assert message.endswith("in the segment spanning t = 50 .. 69 s (thermal: failure injected); check the inputs "
                            "there and the parameters")
    if after is not None:
        assert f"after t = {after} s" in message
    np.testing.assert_allclose(pm.simulate(pm.parameters, seg, 1.0)["temp"], analytic(t, 1.0, 5.0, 3.0), rtol=1e-5)


def test_each_fmu_model_keeps_its_own_failure_message_when_another_was_opened_after_it(thermal_fmu):
    # fmpy sends every FMI 2.0 message to the logger it was given last: the first model's reason must still be its own
    from enginebench.datasets.fmu import SimulationFailed

    first, second = FMUPhysicalModel(config(thermal_fmu)), FMUPhysicalModel(config(thermal_fmu))
    seg = {"time": np.arange(20, dtype=float), "power": np.ones(20)}
    first.simulate(first.parameters, seg, 1.0)
    second.simulate(second.parameters, seg, 1.0)
    with pytest.raises(SimulationFailed, match=r"\(thermal: failure injected\)"):
        first.simulate({**first.parameters, "fail_time": 7.5}, seg, 1.0)


FREED_THEN_DEFAULT = """
import gc, json, sys
import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from enginebench.datasets.fmu import FMUPhysicalModel

cfg = json.loads(sys.argv[1])
pm = FMUPhysicalModel(cfg)
pm.simulate(pm.parameters, {"time": np.arange(5.0), "power": np.ones(5)}, 1.0)
del pm
gc.collect()
md = read_model_description(cfg["fmu"])
fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(cfg["fmu"]), modelIdentifier=md.coSimulation.modelIdentifier,
                instanceName="other")
fmu.instantiate()
fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode()
fmu.setReal([6], [0.5])
fmu.exitInitializationMode()
try:
    fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=1.0)
except Exception as exc:
    print("refused:", exc)
"""


def test_an_fmu_message_after_a_model_was_freed_does_not_crash_the_process(thermal_fmu):
    # a model's logger freed with it left fmpy's one logger slot dangling: the next FMU message was a segfault
    # (an FMU of another module, on fmpy's default callbacks, logging an error); in a child process, as it may crash
    cfg = {k: (str(v) if isinstance(v, Path) else v) for k, v in config(thermal_fmu).items()}
    out = subprocess.run([sys.executable, "-c", FREED_THEN_DEFAULT, json.dumps(cfg)], capture_output=True, text=True, cwd=NEUTRAL,
                         timeout=120)
    assert out.returncode == 0, f"exit {out.returncode}: {out.stderr[-2000:]}"
    assert "refused: fmi2DoStep failed with status 3 (error)" in out.stdout
