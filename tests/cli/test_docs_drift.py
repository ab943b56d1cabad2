"""What the docs and the output say agrees with what the commands do (issue 35, item 6: docs that drift)."""

from __future__ import annotations

import ast
import io
import re
from pathlib import Path

import pytest
from click.testing import CliRunner
from helpers import stored_run
from rich.console import Console

from enginebench.cli.main import cli
from enginebench.results import tables
from enginebench.results.store import RunStore

BOLD_NOTE = "best per block in bold"


@pytest.fixture
def run(tmp_path):
    """Two methods over three repetitions: one best per column, so a table marks it."""
    return stored_run(RunStore(tmp_path / "runs"), "bold", {"a": [1.0, 1.2, 1.1], "b": [2.0, 2.5, 2.2]})


def table(run, *args: str) -> str:
    out = CliRunner().invoke(cli, ["table", run.id, "--store", str(run.path.parent), "--paired", "", *args])
    assert out.exit_code == 0, out.output
    return out.output


def test_the_notes_claim_bold_only_where_bold_is_drawn(run):
    md = table(run, "--format", "md")
    assert "**" in md and BOLD_NOTE in md
    for fmt in ("latex", "html"):
        assert BOLD_NOTE in table(run, "--format", fmt)
    assert BOLD_NOTE not in table(run, "--format", "csv")
    term = table(run, "--width", "200")  # not a terminal: rich draws no bold, so the note must not claim it
    assert "1.1 ±" in term and "over repetitions (n)\n" in term and "in bold" not in term
    summary = tables.summarize(run.metrics())
    assert "in bold" not in tables.to_term(summary, width=200)
    console = Console(file=io.StringIO(), force_terminal=True, color_system="standard", width=100)
    console.print(tables.to_rich(summary, bold=console.color_system is not None))
    drawn = console.file.getvalue()
    assert "\x1b[1m" in drawn and BOLD_NOTE in drawn  # a terminal draws it, and the note says so


def test_table_metrics_all_shows_every_metric_the_run_has(run):
    out = table(run, "--metrics", "all", "--format", "md")
    head = out.splitlines()[0]
    assert "| mae" in head and "| rmse" in head  # rmse is not a default column of a static table
    assert head.index("| mae") < head.index("| rmse")
    csv = table(run, "--metrics", "all", "--format", "csv")
    assert csv.splitlines()[0].startswith("dataset,")
    refused = CliRunner().invoke(cli, ["table", run.id, "--store", str(run.path.parent), "--metrics", "nope"])
    assert refused.exit_code == 2 and "--metrics: unknown metric(s) nope; run " in refused.output


def test_a_plugin_without_a_docstring_shows_its_summary_not_the_base_classs_docstring(tmp_path):
    plugin = tmp_path / "bare_plugin.py"
    plugin.write_text('''
import numpy as np
from enginebench.method import Method

class Bare(Method):
    name = "bare-median"
    family = "baseline"
    summary = "training median, no docstring"
    def fit(self, train, params, rng):
        return np.median(train.y, axis=0)
    def predict(self, fitted, data):
        return [np.tile(fitted, (len(s), 1)) for s in data.segments]
''')
    out = CliRunner().invoke(cli, ["methods", "show", "bare-median", "--plugin", str(plugin)])
    assert out.exit_code == 0, out.output
    assert "Base class of every method" not in out.output
    assert out.output.splitlines()[2:4] == ["", "training median, no docstring"]


PAPER_BY_SEED = re.compile(r"seed ?0\d\d", re.IGNORECASE)
"""The papers' old names (seed 000 ... seed 003): user-facing text names them as docs/papers.md does."""


def test_methods_list_and_show_name_papers_by_their_stable_names():
    from enginebench.registry import available

    listed = CliRunner().invoke(cli, ["methods", "list"])
    assert listed.exit_code == 0 and not PAPER_BY_SEED.search(listed.output), listed.output
    assert "(turboshaft-moe)" in listed.output
    for name in available():
        shown = CliRunner().invoke(cli, ["methods", "show", name])
        assert shown.exit_code == 0 and not PAPER_BY_SEED.search(shown.output), (name, shown.output)


def test_no_user_facing_string_names_a_paper_by_its_old_seed_number():
    """String values (summaries, help, messages, dataset descriptions), not docstrings or comments; the papers
    registry, which maps the old names to the stable ones, is the exception."""
    root = Path(__file__).resolve().parents[2]
    found = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root)
        if rel.parts[0] in ("tests", "build", "benchmarks", "examples") or rel.parts[0].startswith(".") \
                or rel.as_posix() == "enginebench/papers.py":
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"))
        docs = {id(n.value) for n in ast.walk(tree) if isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant)}
        found += [f"{rel}:{n.lineno}" for n in ast.walk(tree) if isinstance(n, ast.Constant)
                  and isinstance(n.value, str) and id(n) not in docs and PAPER_BY_SEED.search(n.value.replace("seed00", ""))]
    assert found == []
