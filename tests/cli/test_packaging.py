"""Installation puts everything under the enginebench package and registers the built-ins."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from importlib.metadata import entry_points
from pathlib import Path, PurePosixPath

import pytest

import enginebench.datasets
import enginebench.methods

FORBIDDEN_TOP_LEVEL = {"datasets", "methods", "results", "cli", "experiments", "benchmarks", "tests"}


def test_the_wheel_puts_everything_under_enginebench(tmp_path):
    """Build the wheel from this checkout: every module sits below enginebench/."""
    pytest.importorskip("setuptools")
    root = Path(__file__).resolve().parents[2]
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(tmp_path), str(root)],
                   check=True, capture_output=True)
    (wheel,) = tmp_path.glob("enginebench-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    tops = {PurePosixPath(n).parts[0] for n in names if not PurePosixPath(n).parts[0].endswith(".dist-info")}
    assert tops == {"enginebench"}, sorted(tops)
    assert not tops & FORBIDDEN_TOP_LEVEL
    assert "enginebench/enginebench/samples.py" in names and "enginebench/cli/main.py" in names
    for data in ("experiments/builtin/gas-turbine-nox.toml", "results/published/gas-turbine-nox-quick.json",
                 "results/published/literature-turboshaft-moe.csv", "datasets/marine_diesel/fat_seed000.csv"):
        assert f"enginebench/{data}" in names, data


def test_subpackages_resolve_inside_enginebench():
    assert enginebench.datasets.__name__ == "enginebench.datasets"
    assert enginebench.methods.__name__ == "enginebench.methods"


def test_console_script_and_builtin_methods_are_registered():
    scripts = {ep.name: ep.value for ep in entry_points(group="console_scripts")}
    assert scripts.get("enginebench") == "enginebench.cli.main:main"
    methods = {ep.name for ep in entry_points(group="enginebench.methods")}
    assert {"naive-mean", "naive-last", "krls"} <= methods


def test_the_all_extra_installs_every_other_extra():
    """``pip install enginebench[all]`` brings every optional extra (the test extra is for the suite, not users)."""
    import re
    import tomllib

    root = Path(__file__).resolve().parents[2]
    extras = tomllib.loads((root / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    (requirement,) = extras["all"]
    named = set(re.fullmatch(r"enginebench\[([a-z,]+)\]", requirement).group(1).split(","))
    assert named == set(extras) - {"all", "test"}
