"""``enginebench export``: a stored model as an FMU (``--fmu``), or the run to MLflow (``--mlflow``, cli/report.py).

The FMU work is ``reports/fmu_export.py``; this module parses and prints.
"""

from __future__ import annotations

import copy
from pathlib import Path

import click

from enginebench.cli import report as _report

_MLFLOW = _report.export
_MLFLOW_NAMES = [p.name for p in _MLFLOW.params]


def _export(**kw) -> None:
    fmu, onnx, uri = kw.get("fmu"), kw.get("onnx"), kw.get("tracking_uri")
    if sum(x is not None for x in (fmu, onnx, uri)) != 1:
        raise click.UsageError("give --fmu OUT.fmu or --onnx OUT.onnx with --method METHOD (a stored model), or "
                               "--mlflow URI (the run to MLflow), one of them")
    if uri is not None:
        return _MLFLOW.callback(**{k: kw[k] for k in _MLFLOW_NAMES})
    if not kw.get("method"):
        raise click.UsageError(f"{'--fmu' if fmu else '--onnx'} needs --method METHOD: the stored model to export")
    if onnx is not None:
        return _export_onnx(kw)
    from enginebench.cli.options import load_plugins
    from enginebench.reports.fmu_export import export_fmu, find_model, result_json
    from enginebench.results.store import RunStore

    load_plugins(kw["plugins"])
    run = RunStore(kw["store"]).get(kw["run_ref"])
    path = find_model(run.path, run.id, kw["method"], kw.get("target"), kw.get("repetition"), kw.get("window"))
    result = export_fmu(path, Path(fmu), timing=kw["timing"], run_id=run.id)
    if kw.get("json_out"):
        click.echo(result_json(result))
    else:
        click.echo(f"wrote {result.path} ({result.method}, job {result.job})")
        click.echo(f"checked with fmpy over {result.steps} test steps against the run's predictions: largest "
                   f"difference {result.max_abs:.3g} absolute, {result.max_rel:.3g} relative "
                   f"(tolerance {result.tolerance:g} relative)")
        for name, fig in result.timing.items():
            label = "C step (the FMU's code, timed in C)" if name == "c_step" else "FMU step through fmpy (Python calls included)"
            click.echo(f"{label}: median {fig['median_us']:.3g} us, p99 {fig['p99_us']:.3g} us, worst "
                       f"{fig['worst_us']:.3g} us; real-time factor dt / worst = {fig['rt_factor']:.3g} "
                       f"(dt = {fig['dt_s']:g} s)")
    if not result.ok:
        result.path.unlink(missing_ok=True)
        from enginebench.errors import MethodError

        raise MethodError(f"the FMU differs from the run's predictions by {result.max_rel:.3g} relative, above "
                          f"{result.tolerance:g}; it was removed (please report this with the run)")


def _export_onnx(kw) -> None:
    from enginebench.cli.options import load_plugins
    from enginebench.reports.fmu_export import find_model
    from enginebench.reports.onnx_export import export_onnx, result_json
    from enginebench.results.store import RunStore

    load_plugins(kw["plugins"])
    run = RunStore(kw["store"]).get(kw["run_ref"])
    path = find_model(run.path, run.id, kw["method"], kw.get("target"), kw.get("repetition"), kw.get("window"))
    result = export_onnx(path, Path(kw["onnx"]), timing=kw["timing"], run_id=run.id)
    if kw.get("json_out"):
        click.echo(result_json(result))
    else:
        click.echo(f"{'wrote' if result.written else 'did not write'} {result.path} (the step) and {result.encoder} "
                   f"(the initial state) ({result.method}, job {result.job})")
        click.echo(f"checked with onnxruntime over {result.steps} test steps against the run's predictions: largest "
                   f"difference {result.max_abs:.3g} absolute, {result.max_rel:.3g} relative "
                   f"(tolerance {result.tolerance:g} relative)")
        for fig in result.timing.values():
            click.echo(f"ONNX step through onnxruntime (Python calls included): median {fig['median_us']:.3g} us, "
                       f"p99 {fig['p99_us']:.3g} us, worst {fig['worst_us']:.3g} us; real-time factor dt / worst = "
                       f"{fig['rt_factor']:.3g} (dt = {fig['dt_s']:g} s)")
    if not result.ok:  # export_onnx removed the unchecked graphs; files already at the paths are untouched
        from enginebench.errors import MethodError

        raise MethodError(f"the ONNX graphs differ from the run's predictions by {result.max_rel:.3g} relative, "
                          f"above {result.tolerance:g}; they were not written (any files already at {result.path} "
                          "and its encoder path are as they were; please report this with the run)")


def _params() -> list[click.Parameter]:
    params = []
    for p in _MLFLOW.params:
        if p.name == "tracking_uri":
            p = copy.copy(p)
            p.required = False
        params.append(p)
    return params + [
        click.Option(["--fmu"], type=click.Path(dir_okay=False), default=None, metavar="OUT.fmu",
                     help="Write an FMI 2.0 co-simulation FMU of the run's stored model of --method (the run needs "
                          "`run --keep-models`), compiled here with gcc, and check it with fmpy against the run's "
                          "test predictions (fails above 1e-9 relative)."),
        click.Option(["--onnx"], type=click.Path(dir_okay=False), default=None, metavar="OUT.onnx",
                     help="Write the run's stored torch model of --method (neural-ss, gru) as ONNX graphs: OUT.onnx "
                          "(one step) and OUT.encoder.onnx (the initial state from the init window), and check them "
                          "with onnxruntime against the run's test predictions (fails above 1e-5 relative for "
                          "float32). Needs the extra onnx."),
        click.Option(["--method"], default=None, help="With --fmu/--onnx: the method whose stored model is exported."),
        click.Option(["--target"], default=None,
                     help="With --fmu/--onnx: the target, when the method has models of several."),
        click.Option(["--window"], type=float, default=None, metavar="SECONDS",
                     help="With --fmu/--onnx: the window (Delta, s), when the method has models of several."),
        click.Option(["--repetition"], type=click.IntRange(min=0), default=None,
                     help="With --fmu/--onnx: the repetition [default: the lowest stored]."),
        click.Option(["--timing"], is_flag=True,
                     help="With --fmu/--onnx: also time each step of the export over the test part."),
        click.Option(["--json", "json_out"], is_flag=True, help="With --fmu/--onnx: print the result as JSON."),
    ]


export = click.Command(
    "export", callback=_export, params=_params(),
    help="Export RUN: --fmu OUT.fmu --method M writes an FMU of its stored model of M, --onnx OUT.onnx --method M "
         "its ONNX graphs (torch models), each checked against the run's test predictions (docs/models.md); "
         "--mlflow URI logs the run to MLflow.\n\n"
         + "\n\n".join((_MLFLOW.help or "").split("\n\n")[1:]),
    short_help="An FMU (--fmu) or ONNX graphs (--onnx) of a stored model, or the run to MLflow (--mlflow).",
)
