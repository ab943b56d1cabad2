"""Conformance checks for Method classes: ``check_method(cls)`` for plugin authors.

A method that passes can be dropped into any experiment: the runner relies on exactly
these properties (a deterministic fit under the job's seed, one array per segment,
predictions that never see the targets, a fitted model and a method that survive
pickling to a worker, and bad input reported as a MethodError line rather than a
traceback). Use it in your plugin's tests::

    from enginebench.testing import check_method
    from my_plugin import MyMethod

    def test_conformance():
        check_method(MyMethod, {"alpha_grid": (-2, 2, 3)})

The checks run on a tiny synthetic dataset (three training and two evaluated segments,
inputs ``u1``, ``u2``, target ``y``) with a linear physical model attached, so hybrid
methods that need one can run too; static, window (two past samples) and simulation
modes are checked, whichever the method supports.

Simulation mode follows the identification protocol: ``fit`` gets whole training
segments; ``predict`` gets evaluated segments whose first ``TINY_INIT`` samples are the
state initialisation window (``y_init``, ``init_samples``; evaluated rows start after it)
and must return ``SegmentPredictions`` (one array of len(s.rows) rows per segment and one
``diverged`` flag per segment). The leakage check perturbs every measured output after
the window: the predictions must not change (the window itself may change them). Bad
input there is a NaN run-time input, a NaN in the initialisation window and a missing
input column. Slow methods can fix hyperparameters with ``params``, e.g.
``check_method(MyODE, params={"epochs": 3})``; ``mode="simulation"`` checks one of the
method's modes only. A method that needs a column the tiny data lacks asks for it with its
role: ``roles={"w": "internal"}`` adds a signal ``w`` measured in training only (the
training samples' ``Z``), ``roles={"w": "input"}`` a run-time input.

The individual checks are ``testing_checks.py`` and the tiny data ``testing_data.py``
(``tiny_samples``, ``TinyLinearPM`` and ``TINY_INIT`` stay importable from here).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

from enginebench.errors import MethodError
from enginebench.method import Method
from enginebench.testing_checks import (CheckFailed, CheckRun, check_attributes, check_bad_input, check_determinism,
                                        check_leakage, check_options, check_pickle, check_shapes)
from enginebench.testing_data import CHECKED_MODES, TINY_INIT, TinyLinearPM, tiny_datasets, tiny_samples

__all__ = ["CHECKS", "TINY_INIT", "ConformanceError", "ConformanceReport", "TinyLinearPM", "check_method",
           "tiny_samples"]

CHECKS = ("attributes", "options", "determinism", "shapes", "no-target-leakage", "pickle-round-trip", "bad-input")
"""The checks, in the order they run."""


class ConformanceError(AssertionError):
    """One or more checks failed; ``failures`` holds (check, message) pairs."""

    def __init__(self, method: str, failures: Sequence[tuple[str, str]], n_checks: int) -> None:
        self.method = method
        self.failures = list(failures)
        lines = "\n".join(f"  - {msg}" for _, msg in self.failures)
        super().__init__(f"method {method!r} failed {len({c for c, _ in self.failures})} of {n_checks} "
                         f"conformance checks:\n{lines}")


@dataclass
class ConformanceReport:
    """What ``check_method`` verified: checks passed, per mode, and anything skipped with why."""

    method: str
    modes: tuple[str, ...]
    passed: list[str] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)


def check_method(cls: type[Method], options: Mapping[str, Any] | None = None, *, seed: int = 0,
                 params: Mapping[str, Any] | None = None, mode: str | None = None,
                 roles: Mapping[str, str] | None = None) -> ConformanceReport:
    """Run every conformance check on ``cls`` (built with ``options``); raise ConformanceError listing failures.

    Each failure message names the check, the method and, where it matters, the mode.
    ``params`` fixes hyperparameters (replacing their search grid) to keep a slow method's
    checks quick, e.g. ``{"epochs": 3}``. ``mode`` checks that mode only (one the class
    declares; default: every mode it declares). ``roles`` adds columns to the tiny data,
    name -> ``"internal"`` or ``"input"``. Returns a report of what passed, per mode.
    """
    options = dict(options or {})
    label = getattr(cls, "name", None) or getattr(cls, "__name__", repr(cls))
    failures: list[tuple[str, str]] = []
    modes = tuple(m for m in CHECKED_MODES if m in getattr(cls, "modes", ()))
    report = ConformanceReport(method=label, modes=modes)

    def fail(check: str, message: str, mode: str | None = None) -> None:
        where = f" ({mode} mode)" if mode else ""
        failures.append((check, f"[{check}] method {label!r}{where}: {message}"))

    try:
        check_attributes(cls)
        report.passed.append("attributes")
    except CheckFailed as exc:
        fail("attributes", str(exc))
        raise ConformanceError(label, failures, len(CHECKS)) from None
    if mode is not None:
        if mode not in modes:
            raise MethodError(f"check_method: method {label!r} declares no checked mode {mode!r}; "
                              f"its modes: {', '.join(modes)}")
        report.modes = modes = (mode,)
    try:
        method = check_options(cls, options)
        report.passed.append("options")
    except CheckFailed as exc:
        fail("options", str(exc))
        raise ConformanceError(label, failures, len(CHECKS)) from None
    train_ds, test_ds = tiny_datasets(seed, roles)
    for mode in modes:
        run = CheckRun(method, train_ds, test_ds, mode, seed, dict(params or {}))
        train, test = run.train, run.test
        steps: list[tuple[str, Callable[[], None]]] = [
            ("no-target-leakage", lambda: check_leakage(run, train, test)),
            ("determinism", lambda: check_determinism(run, train, test)),
            ("shapes", lambda: check_shapes(run, train, test)),
            ("pickle-round-trip", lambda: check_pickle(run, train, test)),
            ("bad-input", lambda: check_bad_input(run, train, test)),
        ]
        for check, step in steps:
            try:
                step()
                report.passed.append(f"{check}[{mode}]")
            except CheckFailed as exc:
                fail(check, str(exc), mode)
    if failures:
        raise ConformanceError(label, failures, len(CHECKS))
    return report
