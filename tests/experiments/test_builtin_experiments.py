"""Every built-in experiment loads, names registered methods whose options are valid and whose
modes include the experiment's, and is listed in docs/protocol.md (the README points there)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from enginebench import registry
from enginebench.experiments.spec import builtin_names, load_spec

DOCS = Path(__file__).resolve().parents[2] / "docs" / "protocol.md"


@pytest.mark.parametrize("name", builtin_names())
def test_builtin_experiment_loads_and_its_methods_accept_their_options(name):
    spec = load_spec(name)
    assert spec.name == name
    for method in spec.methods:
        cls = registry.get(method)
        built = cls(**spec.method_options.get(method, {}))  # a bad option is a MethodError here
        built.check_mode(spec.mode)


def test_every_builtin_experiment_is_listed_in_the_docs():
    text = DOCS.read_text(encoding="utf-8")
    section = text[text.index("## Built-in experiments"):]
    section = section[: section.index("\n## ", 1)]
    listed = set(re.findall(r"`([a-z0-9*-]+)`", section))
    missing = []
    for name in builtin_names():
        quick_family = name.endswith("-quick") and any(
            p.endswith("*-quick") and name.startswith(p[:-len("*-quick")]) for p in listed)
        if name not in listed and not quick_family:
            missing.append(name)
    assert not missing, f"docs/protocol.md 'Built-in experiments' does not list {missing}"
