"""``enginebench calibrate pm``: the FAT table it prints, its exit codes and its parameter file."""

from __future__ import annotations

import json

import click
import numpy as np
import pytest
from click.testing import CliRunner

from enginebench.cli.calibrate import calibrate
from enginebench.cli.main import Group
from enginebench.datasets.marine_diesel.calibration import pm_fat_predictions
from enginebench.datasets.marine_diesel.fat import QUANTITIES, load_fat


@click.group(cls=Group)
def app() -> None:
    """The top-level group as cli/main.py builds it (EngineBenchError -> 'error:' line, exit 2)."""


app.add_command(calibrate)


def invoke(*args: str):
    return CliRunner().invoke(app, ["calibrate", "pm", *args])


def table_rows(output: str) -> dict[tuple[str, float], list[str]]:
    """(quantity, rpm) -> the printed cells FAT, PM, PE, paper PM, paper PE."""
    rows = {}
    for line in output.splitlines():
        parts = line.split()
        if parts and parts[0] in QUANTITIES:
            rows[(parts[0], float(parts[2]))] = parts[3:8]
    return rows


@pytest.fixture(scope="module")
def seed_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("cal") / "params.json"
    result = CliRunner().invoke(app, ["calibrate", "pm", "--fat", "seed", "-o", str(out)])  # the deprecated name
    return result, json.loads(out.read_text())


def test_the_papers_stable_name_gives_the_same_fit_and_the_old_name_one_note(seed_run, tmp_path):
    result, doc = seed_run
    out = tmp_path / "params.json"
    new = CliRunner().invoke(app, ["calibrate", "pm", "--fat", "egt-hybrid", "-o", str(out)])
    assert new.exit_code == 0, new.output
    assert json.loads(out.read_text()) == doc
    note = "note: --fat seed is deprecated (a seed is a random seed); use --fat egt-hybrid"
    assert [line for line in result.output.splitlines() if line.startswith("note:")] == [note]
    assert "deprecated" not in new.output and table_rows(new.output) == table_rows(result.output)
    assert new.stdout == result.stdout  # the note goes to standard error
    default = CliRunner().invoke(app, ["calibrate", "pm"])
    assert default.exit_code == 0 and default.stdout == new.stdout


def test_seed_fixture_calibration_meets_10_percent_and_prints_the_papers_values(seed_run):
    result, doc = seed_run
    assert result.exit_code == 0, result.output
    rows = table_rows(result.output)
    fat = load_fat()
    assert len(rows) == len(QUANTITIES) * len(fat) == 36
    for q in QUANTITIES:
        for i, speed in enumerate(fat["speed_rpm"]):
            fat_v, ours, pe, paper_pm, paper_pe = rows[(q, speed)]
            assert float(fat_v) == pytest.approx(fat[q].iloc[i], rel=1e-4)
            assert abs(float(pe)) <= 10.0
            # the printed PE is the printed PM against the printed FAT value
            assert float(pe) == pytest.approx((float(ours) - float(fat_v)) / float(fat_v) * 100, abs=0.02)
            assert float(paper_pm) == pytest.approx(fat[f"{q}_pm_paper"].iloc[i], rel=1e-4)
            assert float(paper_pe) == pytest.approx(fat[f"{q}_pe_paper_pct"].iloc[i], abs=0.006)
    # the paper's worst error in Table 4 is the turbine-outlet temperature at 631 rpm, 9.916 %
    assert "worst |PE| (paper, egt-hybrid Table 4): 9.92 % (t_turbine_outlet_degc at 631 rpm)" in result.output
    assert "criterion |PE| <= 10 %: met" in result.output


def test_parameter_file_reproduces_the_printed_worst_error(seed_run):
    result, doc = seed_run
    fat = load_fat()
    pred = pm_fat_predictions(doc["params"], fat)
    pe = np.concatenate([(pred[q] - fat[q]).to_numpy() / fat[q].to_numpy() * 100 for q in QUANTITIES])
    worst = float(np.abs(pe).max())
    assert worst == pytest.approx(doc["max_abs_pe_pct"], abs=1e-9)
    assert worst <= 10.0
    assert f"worst |PE| (ours): {worst:.2f} %" in result.output
    assert doc["fat"].startswith("egt-hybrid Table 4") and doc["pressure"] == "absolute"


def test_exit_code_1_when_an_error_exceeds_the_tolerance(seed_run):
    _, doc = seed_run
    tight = doc["max_abs_pe_pct"] - 0.5       # the same fit cannot meet a tighter criterion
    result = invoke("--fat", "seed", "--tolerance", f"{tight:.3f}")
    assert result.exit_code == 1, result.output
    assert "NOT met" in result.output
    assert sum(line.endswith("  !") for line in result.output.splitlines()) >= 1


def test_simulator_fat_has_no_paper_columns_and_fits_closely():
    result = invoke("--fat", "simulator", "--seed", "0")
    assert result.exit_code == 0, result.output
    rows = table_rows(result.output)
    assert len(rows) == 36
    assert all(cells[3] == "-" and cells[4] == "-" for cells in rows.values())
    assert max(abs(float(c[2])) for c in rows.values()) < 5.0
    assert "worst |PE| (paper" not in result.output


def test_default_is_the_papers_fixture():
    assert "default: egt-hybrid" in " ".join(CliRunner().invoke(app, ["calibrate", "pm", "--help"]).output.split())
    assert "1 when any |PE| exceeds it" in " ".join(CliRunner().invoke(app, ["calibrate", "pm", "--help"]).output.split())


@pytest.mark.parametrize("content, message", [
    (None, "file not found"),
    ("", "the file is empty"),
    ("speed_rpm,p_charge_air_bar\n631,1.2\n795,2.0\n", "missing column(s) p_exhaust_receiver_bar"),
    ("BAD", "missing column(s)"),
])
def test_bad_fat_files_give_one_error_line_and_exit_2(tmp_path, content, message):
    path = tmp_path / "fat.csv"
    if content is not None:
        path.write_text(content)
    result = invoke("--fat", str(path))
    assert result.exit_code == 2
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: FAT table ") and message in lines[0]
    assert str(path) in lines[0]


def _fixture_text() -> str:
    return load_fat().to_csv(index=False)


def test_non_numeric_value_names_file_column_and_row(tmp_path):
    text = _fixture_text().splitlines()
    header = text[0].split(",")
    col = header.index("p_max_bar")
    cells = text[3].split(",")
    cells[col] = "n/a?"
    text[3] = ",".join(cells)
    path = tmp_path / "fat.csv"
    path.write_text("\n".join(text) + "\n")
    result = invoke("--fat", str(path))
    assert result.exit_code == 2
    assert "column p_max_bar, data row 3: value 'n/a?' is not a finite number" in result.output


def test_repeated_speed_and_negative_value_are_refused(tmp_path):
    fat = load_fat()
    dup = fat.copy()
    dup.loc[2, "speed_rpm"] = dup.loc[1, "speed_rpm"]
    path = tmp_path / "dup.csv"
    dup.to_csv(path, index=False)
    result = invoke("--fat", str(path))
    assert result.exit_code == 2 and "column speed_rpm, data row 3: speed 795 rpm appears twice" in result.output
    neg = fat.copy()
    neg.loc[0, "sfc_g_per_kwh"] = -1.0
    neg.to_csv(path, index=False)
    result = invoke("--fat", str(path))
    assert result.exit_code == 2 and "column sfc_g_per_kwh, data row 1: value -1 must be positive" in result.output


def test_unknown_dataset_is_refused():
    result = invoke("--dataset", "turboshaft")
    assert result.exit_code == 2
    assert "dataset 'turboshaft' has no FAT-calibrated physical model" in result.output
