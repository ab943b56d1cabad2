"""Options shared by several verbs, and the few helpers every verb uses the same way."""

from __future__ import annotations

from typing import Iterable

import click

from enginebench.errors import DataError

store_option = click.option(
    "--store", type=click.Path(file_okay=False), default=None, envvar="ENGINEBENCH_STORE", show_envvar=True,
    help="Run store folder [default: ./enginebench-runs].",
)
plugin_option = click.option(
    "--plugin", "plugins", multiple=True, type=click.Path(dir_okay=False),
    help="Python file defining extra Method classes (repeatable). A class may not reuse a registered "
         "method's name unless it sets overrides = True.",
)


def load_plugins(plugins: tuple[str, ...]) -> None:
    """Load each --plugin file (one error line naming the file if it fails)."""
    from enginebench.registry import load_plugin_file

    for path in plugins:
        load_plugin_file(path)


def emit(text: str, output: str | None) -> None:
    """Write ``text`` to ``output`` (saying so on stderr) or to standard output."""
    if output:
        from enginebench.results.output import write_output

        write_output(output, text)
        click.echo(f"wrote {output}", err=True)
    else:
        click.echo(text, nl=False)


def check_output(output: str | None, option: str = "--output") -> None:
    """Refuse an output file that cannot be written before any work is done (no-op without one)."""
    if output:
        from enginebench.results.output import check_output_file

        check_output_file(output, option)


def split_list(text: str | None) -> list[str]:
    """A comma-separated option as a list of its non-empty items."""
    return [m.strip() for m in (text or "").split(",") if m.strip()]


def check_metrics(requested: Iterable[str], available: Iterable[str], option: str, run_id: str = "") -> None:
    """Every requested metric must be one the run has: else one line listing those it has."""
    have = sorted(set(available))
    unknown = [m for m in requested if m not in have]
    if unknown:
        where = f"run {run_id} has" if run_id else "the runs have"
        raise DataError(f"{option}: unknown metric(s) {', '.join(unknown)}; {where} {', '.join(have)}")
