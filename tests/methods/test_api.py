"""enginebench.api is the plugin surface: it exports the contract, and the README and example plugin use nothing else."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

import enginebench.api as api
from enginebench.errors import MethodError
from enginebench.method import Method, SegmentPredictions
from enginebench.samples import Samples
from enginebench.testing import check_method

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "enginebench-example-plugin"


def enginebench_imports(source: str) -> list[str]:
    """Every module of the enginebench package that ``source`` imports (import x / from x import y)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [a.name for a in node.names if a.name.split(".")[0] == "enginebench"]
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "enginebench":
            found.append(node.module)
    return found


def test_api_exports_the_contract_objects_themselves():
    assert (api.Method, api.Samples, api.SegmentPredictions, api.MethodError, api.check_method) == (
        Method, Samples, SegmentPredictions, MethodError, check_method)
    assert sorted(api.__all__) == sorted(set(api.__all__))
    missing = [name for name in api.__all__ if not hasattr(api, name)]
    assert missing == []


def test_enginebench_imports_sees_both_import_forms():
    assert enginebench_imports("import numpy\nimport enginebench.testing\nfrom enginebench.api import Method\n") == [
        "enginebench.testing", "enginebench.api"]


def readme_python_blocks(section: str) -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index(f"## {section}")
    body = text[start: text.index("\n## ", start + 3)]
    return re.findall(r"```python\n(.*?)```", body, re.S)


def test_readme_writing_a_method_imports_only_from_the_api():
    blocks = readme_python_blocks("Writing a method")
    assert len(blocks) >= 3  # Ridge, the conformance test, FirstOrder
    for block in blocks:
        assert set(enginebench_imports(block)) <= {"enginebench.api"}, block[:200]
    assert any("from enginebench.api import" in b for b in blocks)


@pytest.mark.parametrize("path", sorted(p.relative_to(EXAMPLE).as_posix() for p in EXAMPLE.rglob("*.py")))
def test_the_example_plugin_imports_only_from_the_api(path):
    source = (EXAMPLE / path).read_text(encoding="utf-8")
    assert set(enginebench_imports(source)) <= {"enginebench.api"}, path
