"""The ``enginebench`` command: one verb per job. Parses, calls the library, prints."""

from __future__ import annotations

import errno
import sys

import click

from enginebench import __version__
from enginebench.errors import EngineBenchError


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


class Group(click.Group):
    """Every refusal is one ``error:`` line on stderr, never a traceback.

    * EngineBenchError anywhere below: its message, exit code 2;
    * a bad command line (unknown option, invalid value, missing argument): click's
      message on one line with the command's ``--help`` named, exit code 2;
    * an OSError that escaped the shared writers (a file that vanished, a full disk):
      the file and the reason, exit code 2 (a broken pipe to ``head`` exits quietly).
    """

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except EngineBenchError as exc:
            click.echo(f"error: {_one_line(exc)}", err=True)
            sys.exit(exc.exit_code)
        except OSError as exc:
            if exc.errno == errno.EPIPE:
                sys.exit(1)
            from enginebench.results.output import os_reason

            where = f" {exc.filename}" if exc.filename else ""
            click.echo(f"error: cannot read or write{where} ({os_reason(exc)}); check the path, its permissions "
                       "and free space, then run again", err=True)
            sys.exit(2)

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode, **extra)
        try:
            rv = super().main(args, prog_name, complete_var, False, **extra)
        except click.exceptions.NoArgsIsHelpError as exc:  # a group named alone: its help
            exc.show()
            sys.exit(exc.exit_code)
        except click.UsageError as exc:
            hint = f"; see '{exc.ctx.command_path} --help'" if exc.ctx is not None else ""
            click.echo(f"error: {_one_line(exc.format_message()).rstrip('.')}{hint}", err=True)
            sys.exit(exc.exit_code)
        except click.ClickException as exc:
            click.echo(f"error: {_one_line(exc.format_message())}", err=True)
            sys.exit(exc.exit_code)
        except click.exceptions.Abort:
            click.echo("Aborted!", err=True)
            sys.exit(1)
        sys.exit(rv if isinstance(rv, int) else 0)


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
    from enginebench.cli import report, runs

    cli.add_command(run.run)
    cli.add_command(datasets.datasets)
    cli.add_command(methods.methods)
    cli.add_command(table.table)
    cli.add_command(runs.runs)
    cli.add_command(rank.rank)
    cli.add_command(compare.compare)
    cli.add_command(compare.guard)
    cli.add_command(compare.publish)
    cli.add_command(calibrate.calibrate)
    cli.add_command(learning_curve.learning_curve)
    cli.add_command(layout.layout)
    cli.add_command(layout.plots)
    cli.add_command(report.report)
    from enginebench.cli import export as export_cmd

    cli.add_command(export_cmd.export)  # --fmu, and --mlflow (report.export)


_register()


def main() -> None:
    cli(prog_name="enginebench")
