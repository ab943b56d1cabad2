"""Commands that print stored results import only what printing needs (issue 35, item 5: start in under a second).

Each command runs in a fresh interpreter started outside the checkout; the test reads that interpreter's
``sys.modules`` afterwards. No timing is asserted (benchmarks/cli_startup.py measures the CPU time): these tests
fail when a heavy module comes back onto a printing path, e.g. scipy for the Student-t quantile of a table's
intervals (results/student_t.py computes it) or pandas for listing runs.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from enginebench.results.store import RunStore
from helpers import stored_run

SCRIPT = """
import json, sys
from enginebench.cli.main import cli
try:
    cli(sys.argv[1:], prog_name="enginebench", standalone_mode=False)
except SystemExit:
    pass
print("\\nMODULES " + json.dumps(sorted(sys.modules)))
"""


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    rs = RunStore(tmp_path_factory.mktemp("startup") / "runs")
    # 30 repetitions whose paired differences tie: the Wilcoxon test's normal approximation
    stored_run(rs, "startup-ties", {"naive-mean": [2.0 + 0.125 * (r % 7) for r in range(30)],
                                    "ridge": [1.0 + 0.25 * (r % 5) for r in range(30)]}, seed=2)
    # 5 repetitions without ties: its exact distribution (the run listed as latest)
    stored_run(rs, "startup", {"naive-mean": [2.0, 2.21, 2.1, 2.33, 1.94], "ridge": [1.0, 1.32, 1.13, 1.08, 1.51]})
    return rs


def _modules(args: list[str], cwd) -> tuple[str, set[str]]:
    done = subprocess.run([sys.executable, "-c", SCRIPT, *args], capture_output=True, text=True, timeout=300,
                          cwd=cwd)
    assert done.returncode == 0, done.stderr
    head, _, tail = done.stdout.rpartition("\nMODULES ")
    return head, set(json.loads(tail))


def _loaded(modules: set[str], package: str) -> list[str]:
    return sorted(m for m in modules if m == package or m.startswith(package + "."))


@pytest.mark.parametrize("name", ["startup", "startup-ties"])
@pytest.mark.parametrize("command", [["table", "RUN"], ["table", "RUN", "--format", "csv"], ["runs", "show", "RUN"]],
                         ids=" ".join)
def test_printing_a_stored_table_imports_no_scipy(store, tmp_path, command, name):
    """The intervals (Student-t quantile) and paired t-tests of a stored run come from results.student_t, the
    Wilcoxon test from results.stats (exact, or its normal approximation where differences tie): neither
    scipy.special nor scipy.stats (nor any other part of scipy) is imported."""
    run = next(r for r in store.runs() if r.config()["name"] == name)
    args = [str(run.path) if a == "RUN" else a for a in command]
    out, modules = _modules([*args, "--store", str(store.root)], tmp_path)
    assert "ridge" in out and "naive-mean" in out  # the command did print the run
    assert "enginebench.results.student_t" in modules
    assert _loaded(modules, "scipy") == []


def test_listing_runs_imports_neither_scipy_nor_pandas(store, tmp_path):
    """runs list reads run.json and counts job files: no data frame, so no pandas (pyarrow stays: the store's
    readers name its errors)."""
    out, modules = _modules(["runs", "list", "--store", str(store.root)], tmp_path)
    assert "startup" in out
    assert _loaded(modules, "pandas") == [] and _loaded(modules, "scipy") == []


def test_listing_methods_imports_no_pandas(tmp_path):
    out, modules = _modules(["methods", "list"], tmp_path)
    assert "naive-mean" in out and "ridge" in out
    assert _loaded(modules, "pandas") == []


def test_every_table_format_has_its_renderer_in_one_registry():
    """``results/formats.py`` is the one place a format is added: each listed name resolves to a function of the
    renderer signature, and the CLI's --format choices are that list."""
    import inspect

    from enginebench.cli.table import table
    from enginebench.results.formats import FORMATS, RENDERERS, renderer

    assert FORMATS == tuple(RENDERERS) == ("term", "md", "latex", "csv", "html")
    for fmt in FORMATS:
        params = inspect.signature(renderer(fmt)).parameters
        assert list(params)[:2] == ["summary", "metrics"], fmt
        assert any(p.kind is p.VAR_KEYWORD for p in params.values()), fmt  # title, units, width: what it needs
    option = next(p for p in table.params if p.name == "fmt")
    assert tuple(option.type.choices) == FORMATS
