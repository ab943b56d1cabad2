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
    from enginebench.results.term import grid

    found, bad = available(), broken()
    rows = [(name, cls.family, ", ".join(sorted(cls.modes)), cls.summary) for name, cls in found.items()]
    rows += [(name, "BROKEN", "-", why) for name, why in bad.items()]
    click.echo(grid(("method", "family", "modes", "summary"), rows, no_wrap=(True, True, False, False),
                    max_width=(None, None, 11, None)), nl=False)


def _wrapped(paragraph: str) -> str:
    from enginebench.results.term import note_text

    if any(line.startswith((" ", "-", "*")) for line in paragraph.splitlines()):
        return paragraph + "\n"
    return note_text([paragraph], hang="")


@methods.command("show")
@click.argument("name")
@plugin_option
def methods_show(name: str, plugins) -> None:
    """Family, modes, the docstring (else the summary) and every option (type, default, unit, meaning) of method NAME."""
    import inspect

    from enginebench.registry import get
    from enginebench.results.term import grid, note_text

    load_plugins(plugins)
    cls = get(name)
    joint = "; joint targets: yes" if getattr(cls, "joint_targets", False) else ""
    click.echo(note_text([f"{cls.name}  ({cls.family}; modes: {', '.join(sorted(cls.modes))}{joint})",
                          f"class: {cls.__module__}.{cls.__qualname__}"]), nl=False)
    own = cls.__dict__.get("__doc__")  # inspect.getdoc would give a base class's docstring to a class without one
    doc = inspect.cleandoc(own) if own else cls.summary
    if doc:  # each paragraph wrapped to the terminal; an indented block (an example) kept as written
        click.echo("\n" + "\n".join(_wrapped(part) for part in doc.split("\n\n")), nl=False)
    rows = cls.option_declaration().rows()
    if rows:
        key = cls.name if cls.name.replace("-", "").replace("_", "").isalnum() else f'"{cls.name}"'
        click.echo(f"\noptions (set them in the experiment's [methods.{key}] table):")
        click.echo(grid(("option", "type", "default", "unit", "meaning"), rows, no_wrap=(True, False, False, True, False),
                        max_width=(None, 14, 12, None, None), indent=2), nl=False)
    click.echo("\n" + note_text([export_line(cls)]), nl=False)


def export_line(cls) -> str:
    """Whether the method's fitted models can be exported (``enginebench export``) and stored (docs/models.md)."""
    from enginebench.c_model import exportable
    from enginebench.methods.export.onnx import onnx_exportable

    if getattr(cls, "export_note", None):
        return f"export: {cls.export_note}"
    if exportable(cls) and "simulation" in cls.modes:
        return "export: FMU (FMI 2.0 co-simulation from its C step: enginebench export RUN --method NAME --fmu OUT.fmu)"
    if onnx_exportable(cls) and "simulation" in cls.modes:
        return ("export: ONNX (its step and initial state as ONNX graphs, checked with onnxruntime: enginebench "
                "export RUN --method NAME --onnx OUT.onnx)")
    return "export: none (this method offers no C step to build an FMU from, nor a torch graph for ONNX)"
