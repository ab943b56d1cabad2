"""``export --window``: a method stored with models of several windows (Delta) is exported only for the window
the user names; without a choice the export is refused in one line naming the windows stored."""

from __future__ import annotations

import pytest

from enginebench.errors import StoreError
from enginebench.reports import fmu_export
from enginebench.results.model_store import MODELS_DIR


@pytest.fixture
def two_windows(tmp_path, monkeypatch):
    folder = tmp_path / MODELS_DIR
    folder.mkdir()
    jobs = {}
    for w, rep in ((0.0, 0), (30.0, 0), (30.0, 1)):
        name = f"y__w{int(w)}__published__krls__r{rep:03d}.npz"
        (folder / name).write_bytes(b"")
        jobs[name] = {"method": "krls", "target": "y", "window": w, "repetition": rep, "split": "published"}
    monkeypatch.setattr(fmu_export, "read_model_file", lambda path: ({"job": jobs[path.name]}, None))
    return tmp_path


def test_several_windows_without_a_choice_are_refused_in_one_line(two_windows):
    with pytest.raises(StoreError, match=r"^run R: method 'krls' stored models of several windows \(0 s, 30 s\); "
                                         r"choose one with --window$"):
        fmu_export.find_model(two_windows, "R", "krls", None, None)


def test_the_named_window_and_the_lowest_repetition_are_exported(two_windows):
    assert fmu_export.find_model(two_windows, "R", "krls", None, None, 30.0).name == "y__w30__published__krls__r000.npz"
    assert fmu_export.find_model(two_windows, "R", "krls", None, 1, 30).name == "y__w30__published__krls__r001.npz"
    assert fmu_export.find_model(two_windows, "R", "krls", None, None, 0).name == "y__w0__published__krls__r000.npz"


def test_a_window_not_stored_names_those_that_are(two_windows):
    with pytest.raises(StoreError, match=r"stored no model of window 5 s; it stored 0 s, 30 s$"):
        fmu_export.find_model(two_windows, "R", "krls", None, None, 5.0)
