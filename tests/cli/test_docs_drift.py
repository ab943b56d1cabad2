"""What the docs and the output say agrees with what the commands do (issue 35, item 6: docs that drift)."""

from __future__ import annotations

import io

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
