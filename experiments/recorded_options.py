"""The options a run's methods ran with, recorded and restored.

A run's config keeps only the options the experiment set; the rest are the methods' defaults
of the version that ran it, and a default may change between versions (narx's ``max_rows``
did). The run records every option (run.json ``method_options``), and a resumed run and the
reports' re-fits build their methods from that record, so they fit the run's own models.
"""

from __future__ import annotations

from typing import Any

from enginebench.errors import EngineBenchError, MethodError
from enginebench.experiments.jobs import Context
from enginebench.results.job_files import jsonable
from enginebench.results.run_folder import Run


def method_options(ctx: Context) -> dict[str, Any]:
    """Every method's options as the run uses them, defaults included (run.json ``method_options``): the config
    keeps only what the experiment set, and a default may change between versions."""
    return {name: jsonable(dict(method.options)) for name, method in ctx.methods.items()}


def with_recorded_options(ctx: Context, run: Run) -> Context:
    """``ctx`` with each method built from the options ``run`` recorded where this version's differ (a default
    changed since), so that a resumed run's jobs and the reports' re-fits use the run's own methods.
    MethodError when a recorded set no longer fits the method (an option removed or renamed)."""
    recorded = run.info().get("method_options") or {}
    for name, options in recorded.items():
        method = ctx.methods.get(name)
        if method is None or jsonable(dict(method.options)) == options:
            continue
        try:
            ctx.methods[name] = type(method)(**options)
        except EngineBenchError as exc:
            raise MethodError(f"run {run.id}: {name}'s options as the run recorded them no longer fit this version "
                              f"of the method ({exc}); its jobs cannot be re-fitted or resumed here") from None
    return ctx
