"""Every terminal table through one renderer (``results.term``): 80 columns, whole names, units in headers, each
note once and wrapped; commands that print stored results import no heavy library (issue 35)."""

from __future__ import annotations

import subprocess
import sys

import pytest
from click.testing import CliRunner

from enginebench.cli.main import cli
from enginebench.results.store import RunStore
from enginebench.results.term import grid, note_text
from helpers import stored_run

NEUTRAL = str(__import__("pathlib").Path(__file__).resolve().parent)
"""A child Python starts here, not in the checkout root, whose ``enginebench/`` source folder would shadow the
installed package (``python -c`` puts its working directory first on sys.path)."""


LONG = "residual-krls-pm-with-a-long-name"


def lines_of(*args, columns: int = 80) -> list[str]:
    out = CliRunner().invoke(cli, list(args), env={"COLUMNS": str(columns)}, terminal_width=columns)
    assert out.exit_code == 0, out.output
    return out.output.splitlines()


def assert_fits(lines: list[str], width: int = 80) -> None:
    long = [line for line in lines if len(line) > width]
    assert not long, "\n".join(long)


@pytest.fixture
def store(tmp_path):
    rs = RunStore(tmp_path / "runs")
    stored_run(rs, "an-experiment-with-a-long-name", {"naive-mean": [2.0, 2.2, 2.1], LONG: [1.0, 1.3, 1.13]},
               dataset="a-dataset-file-with-a-long-name.parquet")
    stored_run(rs, "an-experiment-with-a-long-name", {"naive-mean": [2.1, 2.0, 2.3], LONG: [0.9, 1.2, 1.0]},
               dataset="a-dataset-file-with-a-long-name.parquet")
    return rs


def test_grid_is_plain_text_two_spaces_apart_numbers_right_and_wraps_at_spaces():
    text = grid(["method", "time [s]"], [["krls", "1.5"], ["naive-mean", "22.25"]], right=[False, True])
    assert text == ("method      time [s]\n"
                    "--------------------\n"
                    "krls             1.5\n"
                    "naive-mean     22.25\n")
    wrapped = grid(["name", "meaning"], [["gamma_grid", "kernel widths searched " * 6]], no_wrap=[True, False],
                   width=40).splitlines()
    assert_fits(wrapped, 40)
    assert [line.split()[0] for line in wrapped[:3]] == ["name", "-" * 40, "gamma_grid"]
    assert " ".join(" ".join(line[12:].split()) for line in wrapped[2:]) == " ".join(("kernel widths searched " * 6).split())


def test_note_text_says_each_note_once_wrapped_with_a_hanging_indent():
    note = "warning (3 jobs): krls: " + "a reason that runs on and on " * 5
    text = note_text([note, " ".join(note.split()), "grid edge: other"], 60, indent="  ")
    lines = text.splitlines()
    assert_fits(lines, 60)
    assert lines[0].startswith("  warning (3 jobs): krls: a reason") and all(line.startswith("      ") for line in lines[1:-1])
    assert lines[-1] == "  grid edge: other" and text.count("warning (3 jobs)") == 1


def test_methods_list_and_show_fit_80_columns_with_whole_names():
    listed = lines_of("methods", "list")
    assert_fits(listed)
    assert listed[0].split() == ["method", "family", "modes", "summary"]
    names = {line.split()[0] for line in listed[2:] if not line.startswith(" ")}
    assert {"residual-krls-pm", "sysidentpy-narx", "naive-mean", "ridge"} <= names
    shown = lines_of("methods", "show", "narx")
    assert_fits(shown)
    head = next(i for i, line in enumerate(shown) if line.split()[:1] == ["option"])
    assert shown[head].split() == ["option", "type", "default", "unit", "meaning"]
    options = {line.split()[0] for line in shown[head + 2:] if line.startswith("  ") and line[2:3].strip()}
    assert {"na", "nb", "gamma_grid", "lambda_grid", "exact_max_rows", "envelope"} <= options


def test_datasets_list_fits_80_columns():
    listed = lines_of("datasets", "list")
    assert_fits(listed)
    assert listed[1].split() == ["dataset", "kind", "state", "description"]
    assert {"gas-turbine-emissions", "marine-diesel", "bosch-gengine2"} <= {line.split()[0] for line in listed[3:]
                                                                             if not line.startswith(" ")}


def test_stored_results_fit_80_columns_with_units_and_whole_names(store):
    a, b = store.runs()
    at = ("--store", str(store.root))
    listed = lines_of("runs", "list", *at)
    assert_fits(listed)
    assert listed[0].split()[:3] == ["id", "status", "jobs"] and listed[1].split()[0] == a.id
    shown = lines_of("runs", "show", a.id, *at)
    assert_fits(shown)
    timing = shown.index("mean seconds per job:") if "mean seconds per job:" in shown else None
    summary = next(i for i, line in enumerate(shown) if line.startswith("mean and Student-t 95% interval"))
    assert timing is None or timing < summary
    head = next(i for i in range(summary, len(shown)) if shown[i].startswith("method"))
    assert shown[head].split() == ["method", "metric", "[unit]", "mean", "95%", "interval", "n", "failed"]
    (i,) = [i for i, line in enumerate(shown) if line.split()[:2] == [LONG, "mae"]]
    # mean 1.1433 +- t(2) 4.303 x sd 0.1504 / sqrt(3), 4 significant digits (not pandas' six), the interval wrapped
    assert shown[i].split()[2:] == ["1.143", "[0.7696,", "3", "0"] and shown[i + 1].split() == ["1.517]"]
    table = lines_of("table", a.id, *at)
    assert_fits(table)
    compared = lines_of("compare", a.id, b.id, *at)
    assert_fits(compared)
    assert any(line.split()[:1] == [LONG] for line in compared)


def test_a_grid_edge_pick_is_said_once_the_job_warning_left_out():
    from enginebench.results.notes import run_note_lines

    class Noted:
        def job_notes(self):
            return {"warnings": {("krls", "krls: gamma = 1e+04 selected at the upper edge of its grid [0.1 .. 1e+04]; "
                                          "the optimum may lie beyond it: widen the grid"): 3,
                                 ("krls", "krls: 2 of 9 grid points failed"): 1}}

        def job_metas(self):
            return {f"j{r}": {"method": "krls", "target": "y", "window": 0.0, "split": "test",
                              "search": {"grid_edges": {"gamma": {"edge": "upper", "upper": 1e4, "option": "gamma_grid"}}}}
                    for r in range(3)}

        def info(self):
            return {}

        def environment(self):
            return {}

    assert run_note_lines(Noted()) == [
        "warning (1 job): krls: 2 of 9 grid points failed",
        "grid edge: krls: gamma at the upper edge of its grid (10000) in 3 of 3 repetitions: widen gamma_grid",
    ]


HEAVY = ("torch", "scipy.stats", "plotly", "sklearn", "matplotlib")


@pytest.mark.parametrize("command", [["runs", "list"], ["runs", "show"], ["table"], ["datasets", "list"],
                                     ["methods", "list"], ["methods", "show", "gru"], ["methods", "show", "moe"],
                                     ["methods", "show", "sindy"]],
                         ids=" ".join)
def test_printing_stored_results_imports_no_heavy_library(store, command):
    """Commands that print stored facts import none of torch, scipy.stats, plotly, scikit-learn or matplotlib
    (each in a fresh interpreter; paired differences without ties keep the Wilcoxon test off scipy.stats). Listing
    methods loads every method class, torch's and scikit-learn's too, without importing those libraries."""
    args = command + (["--store", str(store.root)] if command[0] in ("runs", "table") else [])
    script = (
        "import sys\n"
        "from enginebench.cli.main import cli\n"
        "try:\n"
        f"    cli({args!r}, prog_name='enginebench', standalone_mode=False)\n"
        "except SystemExit:\n"
        "    pass\n"
        f"print('HEAVY', [m for m in {HEAVY!r} if m in sys.modules])\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, cwd=NEUTRAL)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "HEAVY []", done.stdout + done.stderr
    if command == ["methods", "list"]:  # every class loaded (a class that failed to import would say BROKEN)
        assert "BROKEN" not in done.stdout
        assert {"gru", "neural-ss", "moe", "sindy", "krls", "ridge", "mtl-krls"} <= {
            line.split()[0] for line in done.stdout.splitlines() if line.strip()}
