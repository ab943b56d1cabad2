"""The ``enginebench`` command: one verb per job. Parses, calls the library, prints."""

from __future__ import annotations

import sys

import click

from enginebench import __version__
from enginebench.errors import EngineBenchError


class Group(click.Group):
    """Turn EngineBenchError anywhere below into one readable line and exit code 2."""

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except EngineBenchError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(exc.exit_code)


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="enginebench")
def cli() -> None:
    """Benchmark physical, data-driven and hybrid engine models under one protocol.

    Typical session: import or generate a dataset, run an experiment, read its table.

    \b
      enginebench datasets import gas-turbine-emissions --from DIR
      enginebench run gas-turbine-nox-quick
      enginebench table latest --format md
    """


def _register() -> None:
    from enginebench.cli import calibrate, compare, datasets, layout, learning_curve, methods, rank, run, table
    from enginebench.cli import report

    cli.add_command(run.run)
    cli.add_command(datasets.datasets)
    cli.add_command(methods.methods)
    cli.add_command(table.table)
    cli.add_command(table.runs)
    cli.add_command(rank.rank)
    cli.add_command(compare.compare)
    cli.add_command(compare.guard)
    cli.add_command(compare.publish)
    cli.add_command(calibrate.calibrate)
    cli.add_command(learning_curve.learning_curve)
    cli.add_command(layout.layout)
    cli.add_command(layout.plots)
    cli.add_command(report.report)
    cli.add_command(report.export)


_register()


def main() -> None:
    cli(prog_name="enginebench")
