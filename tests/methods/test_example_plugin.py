"""The example third-party package installs, registers its method by entry point, and conforms.

It is built and installed into a temporary target folder (``pip install --target``),
not into the virtual environment, so other tests never see its method; the folder is
put on the path of a fresh ``enginebench`` process, which finds the method through the
``enginebench.methods`` entry point group like any installed plugin.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "enginebench-example-plugin"
CLI = [sys.executable, "-c", "from enginebench.cli.main import main; main()"]


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The example package installed into a temporary folder (no dependencies, no build isolation: offline and fast)."""
    pytest.importorskip("setuptools")
    target = tmp_path_factory.mktemp("site")
    source = tmp_path_factory.mktemp("src") / EXAMPLE.name  # a copy: the build leaves build/ and *.egg-info behind
    shutil.copytree(EXAMPLE, source, ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    out = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", "--no-index",
         "--target", str(target), str(source)],
        capture_output=True, text=True, cwd=tmp_path_factory.getbasetemp(),
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert list(target.glob("enginebench_example_plugin-*.dist-info/entry_points.txt"))
    return target


def run_cli(site: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))}
    # cwd outside the checkout: there `python -c` would import the source folder enginebench/
    return subprocess.run([*CLI, *args], env=env, cwd=cwd, capture_output=True, text=True)


def test_methods_list_shows_the_installed_plugin(installed, tmp_path):
    out = run_cli(installed, "methods", "list", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    line = next((ln for ln in out.stdout.splitlines() if "example-ridge" in ln), None)
    assert line is not None, out.stdout
    assert "data-driven" in line
    shown = run_cli(installed, "methods", "show", "example-ridge", cwd=tmp_path)
    assert shown.returncode == 0, shown.stderr
    assert "alpha_grid" in shown.stdout


def test_without_the_package_the_method_is_unknown(tmp_path):
    out = run_cli(tmp_path / "empty", "methods", "list", cwd=tmp_path)
    assert out.returncode == 0 and "example-ridge" not in out.stdout


def test_the_installed_method_passes_check_method(installed, monkeypatch):
    from enginebench.testing import check_method

    monkeypatch.syspath_prepend(str(installed))
    for name in [m for m in sys.modules if m == "enginebench_example" or m.startswith("enginebench_example.")]:
        monkeypatch.delitem(sys.modules, name)
    from enginebench_example import Ridge

    assert Path(sys.modules["enginebench_example"].__file__).is_relative_to(installed)
    report = check_method(Ridge, {"alpha_grid": (-2, 2, 5)})
    assert "no-target-leakage[window]" in report.passed and "pickle-round-trip[static]" in report.passed
