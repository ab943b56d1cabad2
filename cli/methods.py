"""``enginebench methods``: what methods are available and what they take."""

from __future__ import annotations

import click

from enginebench.cli.options import load_plugins, plugin_option


@click.group()
def methods() -> None:
    """List and describe methods (built-in, installed plugins, --plugin files)."""


@methods.command("list")
@plugin_option
def methods_list(plugins) -> None:
    """One line per method: name, family, supported modes, summary (an installed plugin that fails to load: why)."""
    from enginebench.registry import available, broken

    load_plugins(plugins)
    found, bad = available(), broken()
    width = max([14, *(len(n) for n in (*found, *bad))])  # every name aligned, however long
    for name, cls in found.items():
        click.echo(f"{name:<{width}} {cls.family:<12} {','.join(sorted(cls.modes)):<24} {cls.summary}")
    for name, why in bad.items():
        click.echo(f"{name:<{width}} {'BROKEN':<12} {'-':<24} {why}")


@methods.command("show")
@click.argument("name")
@plugin_option
def methods_show(name: str, plugins) -> None:
    """Family, modes, the docstring (else the summary) and every option (type, default, unit, meaning) of method NAME."""
    import inspect

    from enginebench.registry import get

    load_plugins(plugins)
    cls = get(name)
    joint = "; joint targets: yes" if getattr(cls, "joint_targets", False) else ""
    click.echo(f"{cls.name}  ({cls.family}; modes: {', '.join(sorted(cls.modes))}{joint})")
    click.echo(f"class: {cls.__module__}.{cls.__qualname__}")
    own = cls.__dict__.get("__doc__")  # inspect.getdoc would give a base class's docstring to a class without one
    doc = inspect.cleandoc(own) if own else cls.summary
    if doc:
        click.echo("\n" + doc)
    rows = cls.option_declaration().rows()
    if rows:
        key = cls.name if cls.name.replace("-", "").replace("_", "").isalnum() else f'"{cls.name}"'
        click.echo(f"\noptions (set them in the experiment's [methods.{key}] table):")
        head = ("option", "type", "default", "unit", "meaning")
        widths = [max(len(r[i]) for r in (head, *rows)) for i in range(4)]
        for row in (head, *rows):
            click.echo("  " + "  ".join(cell.ljust(w) for cell, w in zip(row, widths)) + "  " + row[4])
