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
    assert "enginebench/samples.py" in names and "enginebench/cli/main.py" in names
    assert "enginebench/reports/static.py" in names and "enginebench/methods/moe/model.py" in names  # found, not listed
    for data in ("experiments/builtin/gas-turbine-nox.toml", "results/published/gas-turbine-nox-quick.json",
                 "results/published/literature-turboshaft-moe.csv", "datasets/marine_diesel/fat_seed000.csv"):
        assert f"enginebench/{data}" in names, data


def test_subpackages_resolve_inside_enginebench():
    assert enginebench.datasets.__name__ == "enginebench.datasets"
    assert enginebench.methods.__name__ == "enginebench.methods"


FOLDERS = ("cli", "datasets", "experiments", "methods", "reports", "results")


@pytest.mark.parametrize("folder", FOLDERS)
def test_a_folder_cannot_load_under_a_second_name(folder):
    """From the checkout root ``import methods.ridge`` would load a second copy beside ``enginebench.methods.ridge``
    (two ``Method`` classes, ``isinstance`` false across them): each folder refuses any name but its own."""
    root = Path(__file__).resolve().parents[2]
    out = subprocess.run([sys.executable, "-c", f"import {folder}"], cwd=root, capture_output=True, text=True)
    assert out.returncode == 1
    assert f"ImportError: import enginebench.{folder}, not {folder}: this folder is mapped" in out.stderr


def test_every_module_is_loaded_once():
    """Importing the whole package loads each source file under one module name only."""
    import importlib
    import pkgutil

    import enginebench

    for folder in FOLDERS:
        package = importlib.import_module(f"enginebench.{folder}")
        for info in pkgutil.walk_packages(package.__path__, f"{package.__name__}."):
            try:
                importlib.import_module(info.name)
            except ImportError:  # an optional extra that is not installed
                continue
    # the package's own folders: the checkout's in an editable install, site-packages/enginebench in a wheel
    roots = [Path(p).resolve() for p in enginebench.__path__]
    roots += [Path(importlib.import_module(f"enginebench.{folder}").__path__[0]).resolve() for folder in FOLDERS]
    by_file: dict[str, list[str]] = {}
    for name, module in list(sys.modules.items()):
        path = getattr(module, "__file__", None)
        if path and any(Path(path).resolve().is_relative_to(root) for root in roots):
            by_file.setdefault(str(Path(path).resolve()), []).append(name)
    twice = {path: names for path, names in by_file.items() if len(names) > 1 and "tests" not in Path(path).parts}
    assert not twice, twice


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
