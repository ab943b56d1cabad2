"""The dataset catalog finds the built-ins where they are declared (a module's ``DATASETS``), in listing order."""

from __future__ import annotations

import sys
import types

import pytest

from enginebench.datasets import catalog
from enginebench.errors import DataError


def test_every_builtin_is_found_in_the_module_that_declares_it_in_listing_order():
    found = catalog.builtin_datasets()
    assert list(found) == ["gas-turbine-emissions", "silverbox", "f16-gvt", "bosch-gengine1", "bosch-gengine2",
                           "turboshaft", "marine-diesel"]
    assert found["silverbox"].importer.__module__ == "enginebench.datasets.sysid_benchmarks"
    assert found["gas-turbine-emissions"].importer.__module__ == "enginebench.datasets.gas_turbine.importer"
    assert [b.kind for b in found.values()] == ["real"] * 5 + ["synthetic"] * 2
    assert "enginebench.datasets.marine_diesel" not in catalog._declaring_modules()  # heavy packages stay unread


def test_a_new_importer_module_is_one_place_and_a_name_declared_twice_is_refused(monkeypatch):
    extra = types.ModuleType("enginebench_test_extra_importer")
    extra.DATASETS = (catalog.Builtin(name="extra", kind="real", description="d", licence="l",
                                      importer=lambda directory: None),)
    monkeypatch.setitem(sys.modules, extra.__name__, extra)
    monkeypatch.setattr(catalog, "_declaring_modules", lambda: ["enginebench.datasets.catalog", extra.__name__])
    found = catalog.builtin_datasets.__wrapped__()
    assert list(found) == ["turboshaft", "marine-diesel", "extra"]  # order 100 (the default): after the numbered
    twice = types.ModuleType("enginebench_test_twice")
    twice.DATASETS = (catalog.Builtin(name="turboshaft", kind="real", description="d", licence="l"),)
    monkeypatch.setitem(sys.modules, twice.__name__, twice)
    monkeypatch.setattr(catalog, "_declaring_modules", lambda: ["enginebench.datasets.catalog", twice.__name__])
    with pytest.raises(DataError, match="^built-in dataset 'turboshaft' is declared twice: in "
                                        "enginebench.datasets.catalog and in enginebench_test_twice; rename one$"):
        catalog.builtin_datasets.__wrapped__()


def test_unknown_dataset_names_the_builtins():
    with pytest.raises(DataError, match="^unknown dataset 'nope'; built-ins: gas-turbine-emissions, silverbox, "):
        catalog.get_builtin("nope")
