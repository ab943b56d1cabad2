"""Every registered method passes ``check_method`` in every mode it declares.

The parameters are read from the registry's entry-point group (the built-ins, the
cascades and any installed plugin), crossed with each class's ``modes``: a new method is
checked without anyone editing a list. Classes registered at run time by other tests
(``registry.register``) are not entry points and are left out on purpose.
"""

from __future__ import annotations

from importlib.metadata import entry_points
from typing import Any

import pytest

from enginebench import registry
from enginebench.method import Method
from enginebench.methods.cascade import Cascade
from enginebench.testing import CHECKS, check_method
from enginebench.testing_data import CHECKED_MODES

FAST: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {
    "moe": ({"device": "cpu", "batch_size": 64}, {"epochs": 3, "n_experts": 2}),
    "neural-ss": ({"steps": 20, "hidden": 8, "batch_size": 16}, {}),
    "gru": ({"steps": 20, "hidden": 8, "batch_size": 16}, {}),
    "boost-fir": ({"max_iter": 10}, {}),
}
"""(options, fixed params) per method name, for SPEED ONLY: fewer epochs, steps or boosting rounds than
the defaults (neural-ss and gru take over a minute each with theirs). Never used to avoid a check;
a cascade gets its components' entries (see ``_fast``)."""


def _registered() -> list[str]:
    """Every method name of the registry's entry-point group (built-ins and installed plugins)."""
    return sorted({ep.name for ep in entry_points(group=registry.ENTRY_POINT_GROUP)})


def _cases() -> list[Any]:
    """(name, mode) for every registered method and each mode it declares; a broken entry point is one case
    that fails when run."""
    cases = []
    for name in _registered():
        try:
            modes = sorted(registry.get(name).modes)
        except Exception:  # reported by the test itself, through registry.get
            modes = [CHECKED_MODES[0]]
        cases += [pytest.param(name, mode, id=f"{name}-{mode}") for mode in modes]
    return cases


def _fast(cls: type[Method]) -> tuple[dict[str, Any], dict[str, Any]]:
    """(options, params) for ``check_method``: ``FAST``'s entry, or for a cascade its components' entries."""
    if not issubclass(cls, Cascade):
        options, params = FAST.get(cls.name, ({}, {}))
        return dict(options), dict(params)
    defaults = cls.default_options()
    options: dict[str, Any] = {}
    down_options, down_params = FAST.get(defaults["downstream"], ({}, {}))
    if down_options:
        options["downstream_options"] = dict(down_options)
    if defaults["source"] == "model":
        up_options, up_params = FAST.get(defaults["upstream"], ({}, {}))
        if up_options:
            options["upstream_options"] = dict(up_options)
        if up_params:
            options["upstream_params"] = dict(up_params)
    return options, dict(down_params)  # the cascade's search space is the downstream's


def _roles(cls: type[Method]) -> dict[str, str]:
    """Columns the tiny data must add: a cascade's intermediates (internal, or a run-time input for an ideal
    baseline that feeds the measured one) and its surrogates (internal)."""
    if not issubclass(cls, Cascade):
        return {}
    defaults = cls.default_options()
    inter = defaults["intermediate"]
    role = "input" if defaults["source"] == "true" else "internal"
    roles = {name: role for name in ([inter] if isinstance(inter, str) else inter)}
    roles.update({name: "internal" for name in defaults["surrogates"]})
    return roles


@pytest.mark.parametrize("name, mode", _cases())
def test_registered_method_conforms(name: str, mode: str) -> None:
    cls = registry.get(name)
    why = cls.available() if callable(getattr(cls, "available", None)) else None
    if why:  # a method backed by an optional package that is not installed here (the peers)
        pytest.skip(f"{name} {why}")
    options, params = _fast(cls)
    report = check_method(cls, options, params=params, mode=mode, roles=_roles(cls))
    assert report.method == name and report.modes == (mode,) and not report.skipped
    assert report.passed == ["attributes", "options"] + [f"{check}[{mode}]" for check in (
        "no-target-leakage", "determinism", "shapes", "pickle-round-trip", "bad-input")]
    assert {check.split("[")[0] for check in report.passed} == set(CHECKS)  # a check added later runs here too


def test_every_cascade_and_builtin_is_a_case() -> None:
    names = {p.values[0] for p in _cases()}
    assert {"cascade", "moe-nfir", "sindy-nfir", "moe-moe", "moe[ideal]", "sindy[ideal]"} <= names
    assert {"naive-mean", "ridge", "pm", "moe", "gru"} <= names
    assert ("naive-mean", "window") in {tuple(p.values) for p in _cases()}


def test_fast_options_name_registered_methods() -> None:
    """A renamed or removed method leaves no stale entry behind (which would silently make its check slow)."""
    assert set(FAST) <= set(_registered())
