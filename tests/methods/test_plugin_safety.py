"""Plugins cannot silently change which code made a table (issue 14, items 8 and 9).

* a plugin file that raises anything at import (``SystemExit`` included) is one error line;
* a plugin class may not take a registered method's name unless it says ``overrides = True``;
* a run records each plugin file's path and SHA-256; ``run --resume`` and ``report``
  refuse a run whose plugin files are absent, changed, not given, or new;
* an installed plugin whose entry point fails to load is listed as broken, and the
  other methods still work.
"""

from __future__ import annotations

import json
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest
from click.testing import CliRunner

from enginebench import registry
from enginebench.cli.main import cli
from enginebench.results.store import RunStore

MEDIAN = '''
import numpy as np
from enginebench.method import Method

class Median(Method):
    """Training median of the target."""
    name = "{name}"
    family = "baseline"
    summary = "training median"
    {extra}
    def fit(self, train, params, rng):
        return np.median(train.y, axis=0) + {offset}
    def predict(self, fitted, data):
        return [np.tile(fitted, (len(s), 1)) for s in data.segments]
'''


def plugin_text(name: str = "median", extra: str = "", offset: float = 0.0) -> str:
    return MEDIAN.format(name=name, extra=extra, offset=offset)


@pytest.fixture(autouse=True)
def clean_registry(monkeypatch):
    """Plugins registered by one test must not leak into the next (one pytest process)."""
    # plugin files loaded by earlier tests of this process are forgotten (a fresh command line knows none)
    monkeypatch.setattr(registry, "_extra", {k: v for k, v in registry._extra.items()
                                             if k not in registry._origin and not v.__module__.startswith("enginebench_plugin_")})
    monkeypatch.setattr(registry, "_origin", {})


@pytest.fixture
def invoke(tmp_path, monkeypatch):
    monkeypatch.setenv("ENGINEBENCH_DATA", str(tmp_path / "data"))
    monkeypatch.setenv("ENGINEBENCH_STORE", str(tmp_path / "runs"))

    def go(*args):
        return CliRunner().invoke(cli, [str(a) for a in args])

    return go


def one_error_line(out) -> str:
    assert out.exit_code == 2, out.output
    lines = out.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), out.output
    return lines[0]


def experiment(tmp_path: Path, dataset: Path, methods: str = "[methods.naive-mean]\n[methods.krls]\n") -> Path:
    exp = tmp_path / "exp.toml"
    exp.write_text(f'name = "plug"\ndataset = "{dataset}"\ntargets = ["y"]\nrepetitions = 2\ntrain_size = 60\n'
                   f'[selection]\nkind = "none"\n{methods}')
    return exp


# -- import failures -------------------------------------------------------------------------------
@pytest.mark.parametrize("body, reason", [
    ("import sys\nsys.exit(0)\n", "SystemExit: 0"),
    ("import sys\nsys.exit('bye')\n", "SystemExit: bye"),
    ("raise SystemExit\n", "SystemExit"),
    ("import nonexistent_module_xyz\n", "ModuleNotFoundError: No module named 'nonexistent_module_xyz'"),
    ("def f(:\n", "SyntaxError: "),
    ("x = 1 / 0\n", "ZeroDivisionError: division by zero"),
    ("raise GeneratorExit('odd')\n", "GeneratorExit: odd"),
])
def test_a_plugin_failing_at_import_is_one_error_line(invoke, tmp_path, body, reason):
    bad = tmp_path / "bad_plugin.py"
    bad.write_text(body)
    for args in (["methods", "list"], ["methods", "show", "krls"]):
        line = one_error_line(invoke(*args, "--plugin", bad))
        assert line.startswith(f"error: plugin file {bad}: {reason}")
        assert line.endswith("(raised while importing it); fix the plugin")


# -- shadowing ---------------------------------------------------------------------------------------
def test_a_plugin_may_not_take_a_builtin_name_unless_it_says_so(invoke, tmp_path):
    shadow = tmp_path / "shadow.py"
    shadow.write_text(plugin_text("krls"))
    line = one_error_line(invoke("methods", "list", "--plugin", shadow))
    assert line == (f"error: plugin file {shadow}: class Median takes the name 'krls', already registered by "
                    "enginebench.methods.krls.KRLS; rename it, or set overrides = True in the class to replace 'krls' "
                    "on purpose")
    assert registry.get("krls").__module__ == "enginebench.methods.krls"
    shadow.write_text(plugin_text("krls", extra="overrides = True"))
    out = invoke("methods", "show", "krls", "--plugin", shadow)
    assert out.exit_code == 0 and "class: enginebench_plugin_shadow.Median" in out.output


def test_two_plugin_files_may_not_share_a_name_but_one_file_may_be_loaded_again(tmp_path):
    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text(plugin_text("median"))
    b.write_text(plugin_text("median", offset=1.0))
    registry.load_plugin_file(a)
    registry.load_plugin_file(a)  # the same file again: not shadowing
    with pytest.raises(registry.MethodError, match=f"already registered by plugin file {a.resolve()}"):
        registry.load_plugin_file(b)
    assert registry.plugin_origin("median") == (str(a.resolve()), registry.file_sha256(a))


# -- runs record their plugin files ------------------------------------------------------------------
def test_resume_refuses_a_run_whose_plugin_is_missing_changed_or_new(invoke, tmp_path, toy_parquet):
    """The issue's case: a plugin `krls` made the run; resuming without it would mix two methods into one table."""
    plugin = tmp_path / "my_krls.py"
    plugin.write_text(plugin_text("krls", extra="overrides = True"))
    digest = registry.file_sha256(plugin)
    exp = experiment(tmp_path, toy_parquet)
    out = invoke("run", exp, "--plugin", plugin, "-j", "1", "-q")
    assert out.exit_code == 0, out.output
    (run,) = RunStore(tmp_path / "runs").runs()
    assert run.info()["plugins"] == [{"path": str(plugin.resolve()), "sha256": digest, "methods": ["krls"]}]
    shown = invoke("runs", "show", run.id)
    assert f"plugin file: {plugin.resolve()} (sha256 {digest[:12]}; methods krls)" in shown.output

    # same plugin file: resumable (nothing left to do)
    assert invoke("run", "--resume", run.id, "--plugin", plugin, "-q").exit_code == 0
    registry._extra.pop("krls"), registry._origin.pop("krls")  # a fresh process: only what the command line loads

    before = {p.name: p.read_bytes() for p in run.path.rglob("*") if p.is_file()}
    tail = "; use the plugin files the run was made with (`enginebench runs show` lists them)"
    line = one_error_line(invoke("run", "--resume", run.id, "-q"))
    assert line == (f"error: run {run.id} cannot be resumed: plugin file {plugin.resolve()} (method 'krls') is not "
                    f"loaded: pass --plugin {plugin.resolve()}" + tail)
    line = one_error_line(invoke("report", run.id, "-o", tmp_path / "rep"))
    assert line.startswith(f"error: run {run.id} cannot be re-fitted for the report's figures (--no-figures writes the "
                           f"tables only): plugin file {plugin.resolve()} (method 'krls') is not loaded")
    assert not (tmp_path / "rep").exists()

    changed = plugin_text("krls", extra="overrides = True", offset=5.0)
    plugin.write_text(changed)
    new_digest = registry.file_sha256(plugin)
    line = one_error_line(invoke("run", "--resume", run.id, "-q", "--plugin", plugin))
    assert line == (f"error: run {run.id} cannot be resumed: method 'krls' comes from plugin file {plugin.resolve()} "
                    f"(sha256 {new_digest[:12]}), the run used {plugin.resolve()} (sha256 {digest[:12]})" + tail)
    registry._extra.pop("krls"), registry._origin.pop("krls")
    line = one_error_line(invoke("run", "--resume", run.id, "-q"))
    assert f"plugin file {plugin.resolve()} (method 'krls') changed since the run (sha256 {digest[:12]} then, " \
           f"{new_digest[:12]} now)" in line
    plugin.unlink()
    line = one_error_line(invoke("run", "--resume", run.id, "-q"))
    assert f"plugin file {plugin.resolve()} (method 'krls') is absent" in line
    # a copy with the same content elsewhere is the same code
    moved = tmp_path / "moved" / "my_krls.py"
    moved.parent.mkdir()
    moved.write_text(plugin_text("krls", extra="overrides = True"))
    assert invoke("run", "--resume", run.id, "-q", "--plugin", moved).exit_code == 0
    after = {p.name: p.read_bytes() for p in run.path.rglob("*") if p.is_file()}
    assert {k: v for k, v in after.items() if k != "run.json"} == {k: v for k, v in before.items() if k != "run.json"}


def test_a_run_made_without_plugins_refuses_one_that_overrides_its_method(invoke, tmp_path, toy_parquet):
    exp = experiment(tmp_path, toy_parquet, "[methods.naive-mean]\n")
    assert invoke("run", exp, "-j", "1", "-q").exit_code == 0
    (run,) = RunStore(tmp_path / "runs").runs()
    assert run.info()["plugins"] == []
    plugin = tmp_path / "mean.py"
    plugin.write_text(plugin_text("naive-mean", extra="overrides = True"))
    line = one_error_line(invoke("run", "--resume", run.id, "-q", "--plugin", plugin))
    assert f"method 'naive-mean' now comes from plugin file {plugin.resolve()}, the run used the registered one" in line


def test_a_plugin_method_of_its_own_name_is_recorded_and_needed(invoke, tmp_path, toy_parquet):
    plugin = tmp_path / "med.py"
    plugin.write_text(plugin_text("median"))
    exp = experiment(tmp_path, toy_parquet, "[methods.naive-mean]\n[methods.median]\n")
    assert invoke("run", exp, "-j", "1", "-q", "--plugin", plugin).exit_code == 0
    (run,) = RunStore(tmp_path / "runs").runs()
    assert [r["methods"] for r in run.info()["plugins"]] == [["median"]]
    registry._extra.pop("median"), registry._origin.pop("median")
    line = one_error_line(invoke("run", "--resume", run.id, "-q"))
    assert f"plugin file {plugin.resolve()} (method 'median') is not loaded" in line


# -- broken installed plugins --------------------------------------------------------------------------
class _ExitingEntryPoint:
    name, value, group = "exits-at-import", "exiting_pkg:Method", registry.ENTRY_POINT_GROUP

    def load(self):
        raise SystemExit(3)


def test_a_broken_installed_plugin_is_listed_and_refused_by_name_only(invoke, monkeypatch):
    real = registry.entry_points

    def eps(group):
        return [*real(group=group), _ExitingEntryPoint(),
                EntryPoint("missing-module", "no_such_pkg_xyz.mod:Cls", registry.ENTRY_POINT_GROUP)]

    monkeypatch.setattr(registry, "entry_points", eps)
    out = invoke("methods", "list")
    assert out.exit_code == 0, out.output
    lines = out.output.splitlines()
    assert any(x.startswith("krls ") for x in lines)
    assert any(" ".join(x.split()) == "exits-at-import BROKEN - entry point exits-at-import = exiting_pkg:Method "
               "failed to load: SystemExit: 3" for x in lines)  # columns aligned to the longest name
    assert any(x.startswith("missing-module") and "ModuleNotFoundError: No module named 'no_such_pkg_xyz'" in x
               for x in lines)
    line = one_error_line(invoke("methods", "show", "exits-at-import"))
    assert line == ("error: method 'exits-at-import' cannot be used: entry point exits-at-import = exiting_pkg:Method "
                    "failed to load: SystemExit: 3; reinstall or fix that package")
    assert invoke("methods", "show", "krls").exit_code == 0


def test_run_json_plugins_entry_must_be_a_list(tmp_path, toy_parquet, invoke):
    exp = experiment(tmp_path, toy_parquet, "[methods.naive-mean]\n")
    assert invoke("run", exp, "-j", "1", "-q").exit_code == 0
    (run,) = RunStore(tmp_path / "runs").runs()
    info = run.info()
    (run.path / "run.json").write_text(json.dumps({**info, "plugins": "x.py"}))
    line = one_error_line(invoke("run", "--resume", run.id, "-q"))
    assert line.startswith(f"error: run {run.id}: run.json has a 'plugins' entry that is not a list of objects")
