"""--executor slurm (issue 34, item 2): job arrays through submitit, run here by submitit's local executor; the
table equals the local run's; results a dead driver's tasks left are stored on resume, not computed again."""

from __future__ import annotations

import pickle

import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.datasets.io import write_dataset
from enginebench.errors import SpecError
from enginebench.experiments.engine import plan
from enginebench.experiments.executors import EXECUTORS
from enginebench.experiments.jobs import run_job
from enginebench.experiments.runner import context_of_run, run_experiment
from enginebench.experiments.slurm import _minutes, submitit_parameters
from enginebench.experiments.slurm_settings import parse_slurm_options, resources
from enginebench.experiments.spec import from_dict
from enginebench.results.store import RunStore
from helpers import interrupt_after, make_toy

submitit = pytest.importorskip("submitit", reason="the slurm executor needs submitit (pip install enginebench[slurm])")


def spec_of(data, **changes):
    raw = {"name": "toy-slurm", "dataset": str(data), "targets": ["y"], "repetitions": 2, "seed": 7,
           "train_size": 150, "selection": {"kind": "bootstrap", "resamples": 2},
           "methods": {"naive-mean": {}, "ridge": {}}}
    raw.update(changes)
    return from_dict(raw, origin="test")


@pytest.fixture
def data(tmp_path):
    return write_dataset(make_toy(), tmp_path / "toy.parquet")


def test_the_submitit_local_executor_gives_the_local_runs_table(tmp_path, data, monkeypatch):
    monkeypatch.chdir(tmp_path)  # tasks start their Python here: in the checkout, enginebench/ would shadow the install
    slurm = {"cluster": "local", "max_parallel": 2, "methods": {"ridge": {"cpus": 1, "time": 5, "memory": "1G"}}}
    spec = spec_of(data, slurm=slurm)
    store = RunStore(tmp_path / "store")
    local = run_experiment(spec_of(data), store, workers=1).run
    remote = run_experiment(spec, store, workers=1, executor="slurm").run
    assert spec.config_hash() == spec_of(data).config_hash()  # resources never change a result
    assert remote.config()["slurm"]["methods"]["ridge"] == {"cpus": 1, "time": 5, "memory": "1G"}
    assert remote.finished_jobs() == local.finished_jobs() and len(remote.finished_jobs()) == 4
    out = [CliRunner().invoke(cli, ["table", r.id, "--format", "csv", "--store", str(store.root)]).stdout
           for r in (local, remote)]
    assert out[0] == out[1] and "ridge" in out[0]
    logs = list((remote.path / "slurm" / "logs").glob("*_log.out"))
    assert len(logs) == 4  # one task per job, two arrays (one per method)
    assert not list((remote.path / "slurm" / "results").iterdir())  # every result moved into the store
    assert not list((remote.path / "slurm").glob("context-*.pkl"))


def test_resume_stores_what_a_dead_drivers_tasks_left_and_submits_the_rest(tmp_path, data):
    store = RunStore(tmp_path / "store")
    spec = spec_of(data, slurm={"cluster": "debug"})
    stopped = interrupt_after(spec, store, jobs=1, workers=1)
    ctx = context_of_run(stopped)
    missing = [j for j in plan(ctx) if j.key not in stopped.finished_jobs()]
    assert len(missing) == 3
    left = missing[1]  # a task of the dead driver finished and wrote its result; nobody stored it
    rows, meta = run_job(ctx, left)
    results = stopped.path / "slurm" / "results"
    results.mkdir(parents=True)
    (results / f"{left.key}.pkl").write_bytes(pickle.dumps((left, (rows, {**meta, "left_by": "dead driver"}))))
    (results / f".{left.key}.pkl.x.tmp").write_bytes(b"half")  # a task killed mid-write
    resumed = run_experiment(None, store, resume=store.get(stopped.id), workers=1, executor="slurm").run
    assert len(resumed.finished_jobs()) == 4 and resumed.info()["status"] == "finished"
    assert resumed.job_meta(left.key)["left_by"] == "dead driver"  # stored as it was, not computed again
    assert all("left_by" not in resumed.job_meta(j.key) for j in missing if j != left)
    assert not list(results.iterdir())
    full = run_experiment(spec_of(data), store, workers=1).run
    cli_table = [CliRunner().invoke(cli, ["table", r.id, "--format", "csv", "--store", str(store.root)]).stdout
                 for r in (resumed, full)]
    assert cli_table[0] == cli_table[1]


@pytest.mark.parametrize("slurm, message", [
    ({"partion": "cpu"}, "test: [slurm]: unknown key(s) partion (did you mean 'partition'?)"),
    ({"time": "two hours"}, 'must be minutes (a whole number >= 1) or SLURM time text such as "02:00:00"'),
    ({"memory": -1}, 'must be GB (a number > 0) or SLURM text such as "500M" or "16G", got -1'),
    ({"cluster": "pbs"}, "cluster"),
    ({"methods": {"krls": {"cpus": 4}}}, "test: [slurm.methods] gives resources for method(s) not run: krls"),
    ({"methods": {"ridge": {"max_parallel": 4}}}, "[slurm.methods.ridge]"),
])
def test_a_bad_slurm_table_is_one_spec_error(data, slurm, message):
    with pytest.raises(SpecError) as err:
        spec_of(data, slurm=slurm)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_resources_per_method_become_submitit_parameters(data):
    spec = spec_of(data, slurm={"partition": "cpu", "time": "01:30:00", "cpus": 2, "memory": 4, "max_parallel": 8,
                                "setup": ["module load python"], "methods": {"ridge": {"partition": "big",
                                                                                      "memory": "64G"}}})
    ridge = submitit_parameters(resources(spec.slurm, "ridge"), 8, ["module load python"], "enginebench-ridge")
    assert ridge == {"name": "enginebench-ridge", "cpus_per_task": 2, "slurm_array_parallelism": 8,
                     "slurm_time": "01:30:00", "timeout_min": 90, "slurm_mem": "64G", "slurm_partition": "big",
                     "slurm_setup": ["module load python"]}
    naive = submitit_parameters(resources(spec.slurm, "naive-mean"), 8, [], "n")
    assert naive["slurm_partition"] == "cpu" and naive["mem_gb"] == 4 and "slurm_mem" not in naive
    assert [_minutes(t) for t in ("45", "10:30", "1:00:00", "2-00:00:00", "1-12")] == [45, 11, 60, 2880, 2160]


def test_slurm_options_on_the_command_line(tmp_path, data):
    assert parse_slurm_options(["partition=gpu", "time=120", "memory=1.5", "setup=a", "setup=b"]) == {
        "partition": "gpu", "time": 120, "memory": 1.5, "setup": ["a", "b"]}
    with pytest.raises(SpecError, match="^--slurm 'partition': give KEY=VALUE"):
        parse_slurm_options(["partition"])
    result = CliRunner().invoke(cli, ["run", str(tmp_path / "x.toml"), "--slurm", "partition=cpu",
                                      "--store", str(tmp_path / "s")])
    assert result.exit_code == 2 and "--slurm KEY=VALUE sets resources of --executor slurm" in result.output
    result = CliRunner().invoke(cli, ["run", "x", "--executor", "pbs"])
    assert result.exit_code == 2 and all(name in result.output for name in EXECUTORS)
    assert EXECUTORS == ("local", "dask", "slurm")


def test_no_slurm_on_this_machine_is_one_error_line(tmp_path, data, monkeypatch):
    import shutil

    if shutil.which("srun"):
        pytest.skip("srun is on this machine")
    monkeypatch.setenv("ENGINEBENCH_STORE", str(tmp_path / "runs"))
    exp = tmp_path / "exp.toml"
    exp.write_text(f'name = "toy-slurm"\ndataset = "{data}"\ntargets = ["y"]\nrepetitions = 1\n'
                   'train_size = 150\n[methods.naive-mean]\n')
    out = CliRunner().invoke(cli, ["run", str(exp), "--executor", "slurm", "-q"])
    assert out.exit_code == 2, out.output
    assert out.output.strip().splitlines()[-1].startswith(
        "error: the slurm executor found no SLURM here (Could not detect \"srun\", are you indeed on a slurm cluster?); "
        "run on a cluster's login node, or set [slurm] cluster = \"local\" to run the tasks on this machine")
