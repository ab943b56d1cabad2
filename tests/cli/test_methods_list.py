"""`methods list`: one aligned line per method."""

from __future__ import annotations


def test_methods_list_aligns_every_name():
    from click.testing import CliRunner

    from enginebench.cli.main import cli

    lines = CliRunner().invoke(cli, ["methods", "list"]).output.splitlines()
    assert lines[0].split() == ["method", "family", "modes", "summary"] and set(lines[1]) == {"-"}
    starts = {line.index(line.split()[1], len(line.split()[0])) for line in lines[2:]}
    assert len(starts) == 1 and any(line.startswith("residual-krls-pm ") for line in lines)
