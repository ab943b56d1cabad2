"""The layers of the package, read from the source with ast: no import runs upward, none runs in a circle.

    enginebench/ (errors, declare, papers, samples, method, registry, physical, c_model)   the contracts
        <- datasets/, methods/, results/   (each stands on the contracts alone)
        <- experiments/             (the protocol engine)
        <- reports/                 (pages and figures of stored runs; they re-fit through the engine)
        <- cli/ and the facades enginebench/api.py, testing*.py, ...

Every import counts, the ones inside functions included. docs/design.md draws the same picture.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("cli", "datasets", "experiments", "methods", "reports", "results")
CONTRACTS = {"errors", "declare", "papers", "samples", "method", "registry", "physical", "c_model"}
"""The root package's modules that every layer stands on; the other root modules are facades over the layers."""
BELOW = {
    "contracts": set(),
    "datasets": {"contracts"},
    "methods": {"contracts"},
    "results": {"contracts"},
    "experiments": {"contracts", "datasets", "methods", "results"},
    "reports": {"contracts", "datasets", "methods", "results", "experiments"},
    "facades": {"contracts", "datasets", "methods", "results", "experiments", "reports", "cli"},
    "cli": {"contracts", "datasets", "methods", "results", "experiments", "reports", "facades"},
}
"""What each layer may import besides itself: ``methods``, ``datasets`` and ``results`` stand on the contracts alone;
the command line and the Python facades (``enginebench.run`` shows the command line's progress bar) are one top layer."""
def modules() -> dict[str, Path]:
    """Import name -> source file, for every module of the package as pyproject.toml maps the folders."""
    found = {}
    for top, name in [("enginebench", "enginebench"), *((f, f"enginebench.{f}") for f in FOLDERS)]:
        for path in sorted((ROOT / top).rglob("*.py")):
            parts = path.relative_to(ROOT / top).with_suffix("").parts
            parts = parts[:-1] if parts[-1] == "__init__" else parts
            found[".".join((name, *parts))] = path
    return found


MODULES = modules()


def layer(module: str) -> str:
    parts = module.split(".")
    if len(parts) > 1 and parts[1] in FOLDERS:
        return parts[1]
    return "contracts" if len(parts) > 1 and parts[1] in CONTRACTS else "facades"


def imports(module: str) -> list[tuple[str, int]]:
    """(imported module of the package, line) for every import in ``module``'s source, nested ones included."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join([*package.split(".")[: len(package.split(".")) - node.level + 1], *filter(None, [base])])
            names = [f"{base}.{a.name}" for a in node.names]  # a submodule, or else its package
        else:
            continue
        for name in names:
            while name and name not in MODULES:
                name = name.rpartition(".")[0]
            if name and name != module and name != "enginebench":
                out.append((name, node.lineno))
    return sorted(set(out))


GRAPH = {m: imports(m) for m in MODULES if m != "enginebench"}  # the package face only hands names on


def upward(module: str, imported: str) -> bool:
    """True when ``module`` may not import ``imported``: a layer above it or beside it."""
    a, b = layer(module), layer(imported)
    return a != b and b not in BELOW[a]


def test_the_folders_are_read():
    assert {"enginebench.samples", "enginebench.method", "enginebench.registry", "enginebench.experiments.runner",
            "enginebench.reports.static", "enginebench.cli.main"} <= set(MODULES)


@pytest.mark.parametrize("module", sorted(GRAPH))
def test_no_import_runs_upward(module):
    bad = [f"{MODULES[module].relative_to(ROOT)}:{line} imports {name} ({layer(module)} -> {layer(name)})"
           for name, line in GRAPH[module] if upward(module, name)]
    assert not bad, "; ".join(bad)


def circles() -> list[set[str]]:
    """The strongly connected groups of more than one module (Tarjan), every import counted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w, _ in GRAPH.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = set()
            while True:
                w = stack.pop()
                group.add(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(group)

    for v in GRAPH:
        if v not in index:
            visit(v)
    return found


def test_no_circle():
    """No module imports, even from inside a function, one that imports it back (directly or through others).

    Where two modules need the same piece, it lives in a module both import (cli/interrupt.py,
    experiments/executor_base.py, datasets/fmu_dataset.py, datasets/marine_diesel/physical_model.py)."""
    found = [sorted(c) for c in circles()]
    assert not found, f"modules that import each other: {found}"


def test_the_circle_check_finds_a_circle_through_a_nested_import(monkeypatch):
    """The check itself: the catalog's spec import reaching the catalog again (as FMU calibration once did) is caught."""
    chain = ["enginebench.datasets.catalog", "enginebench.datasets.importer", "enginebench.datasets.fmu",
             "enginebench.datasets.fmu_calibrate"]
    for a, b in zip(chain, chain[1:] + chain[:1]):
        monkeypatch.setitem(GRAPH, a, [*GRAPH[a], (b, 0)])
    assert set(chain) in circles()


def test_the_layering_check_fails_on_an_upward_import():
    """The check itself: a dataset module importing the engine, or a contract importing a method, is caught."""
    assert upward("enginebench.datasets.io", "enginebench.experiments.runner")
    assert upward("enginebench.method", "enginebench.methods.ridge")
    assert upward("enginebench.methods.ridge", "enginebench.datasets.io")  # side by side: neither imports the other
    assert upward("enginebench.results.store", "enginebench.api")
    assert upward("enginebench.results.store", "enginebench.methods.ridge")  # results stand on the contracts
    assert not upward("enginebench.reports.static", "enginebench.experiments.runner")
    assert not upward("enginebench.methods.ridge", "enginebench.samples")
