"""Options shared by several verbs."""

from __future__ import annotations

import click

store_option = click.option(
    "--store", type=click.Path(file_okay=False), default=None, envvar="ENGINEBENCH_STORE", show_envvar=True,
    help="Run store folder [default: ./enginebench-runs].",
)
plugin_option = click.option(
    "--plugin", "plugins", multiple=True, type=click.Path(dir_okay=False),
    help="Python file defining extra Method classes (repeatable).",
)


def load_plugins(plugins: tuple[str, ...]) -> None:
    from enginebench.methods.registry import load_plugin_file

    for path in plugins:
        load_plugin_file(path)


def emit(text: str, output: str | None) -> None:
    """Write ``text`` to ``output`` (saying so on stderr) or to standard output."""
    if output:
        with open(output, "w", encoding="utf-8") as fh:
            fh.write(text)
        click.echo(f"wrote {output}", err=True)
    else:
        click.echo(text, nl=False)
