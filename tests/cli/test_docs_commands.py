"""Every ``enginebench ...`` command written in README.md and docs/*.md names a real verb, real options and, where
it names one literally, a real built-in experiment or choice (issue 35, item 6): a renamed option fails here."""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import click
import pytest

from enginebench.cli.main import cli

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^\s*(```|~~~)")
SPAN = re.compile(r"`([^`]+)`")
SHELL_BREAKS = {"|", "||", "&&", ";", ">", ">>", "2>", "2>&1", "<"}
EXPERIMENT_VERBS = {("run",), ("learning-curve",)}
"""Verbs whose first argument is an experiment: a literal name there (no .toml, not a placeholder) must be built in."""


@dataclass(frozen=True)
class DocCommand:
    where: str
    """file:line of the command."""
    text: str
    args: tuple[str, ...]
    """The words after ``enginebench``, up to a pipe or redirection."""


def _words(text: str) -> list[str] | None:
    try:
        return shlex.split(text, comments=True)
    except ValueError:  # an unbalanced quote in prose: not a command
        return None


def _command(where: str, text: str) -> DocCommand | None:
    words = _words(text)
    if not words or "enginebench" not in words:
        return None
    args = []
    for w in words[words.index("enginebench") + 1:]:
        if w in SHELL_BREAKS:
            break
        args.append(w)
    return DocCommand(where, text.strip(), tuple(args))


def doc_commands() -> list[DocCommand]:
    """Commands in code blocks (a line starting with ``enginebench`` or ``$ enginebench``, continued by ``\\``) and
    inline code spans that start with ``enginebench`` (a paragraph's lines joined, so a span may wrap)."""
    found = []
    for path in DOCS:
        rel = path.relative_to(ROOT).as_posix()
        lines = path.read_text(encoding="utf-8").splitlines()
        in_code, paragraph, start, pending = False, [], 0, ""
        for no, line in enumerate(lines + [""], start=1):
            if FENCE.match(line):
                in_code, pending = not in_code, ""
                continue
            if in_code:
                text = pending + line.strip()
                if text.endswith("\\"):
                    pending = text[:-1] + " "
                    continue
                pending = ""
                body = text[2:] if text.startswith("$ ") else text
                if body.startswith("enginebench ") or re.match(r"^[A-Z_]+=\S+ enginebench ", body):
                    cmd = _command(f"{rel}:{no}", body)
                    if cmd:
                        found.append(cmd)
                continue
            if line.strip():
                paragraph.append(line.strip())
                start = start or no
                continue
            for span in SPAN.findall(" ".join(paragraph)):
                if span.startswith("enginebench "):
                    cmd = _command(f"{rel}:{start}", span)
                    if cmd:
                        found.append(cmd)
            paragraph, start = [], 0
    return found


def _option_names(command: click.Command) -> dict[str, click.Option]:
    names: dict[str, click.Option] = {"--help": None, "-h": None}  # type: ignore[dict-item]
    for p in command.params:
        if isinstance(p, click.Option):
            for n in (*p.opts, *p.secondary_opts):
                names[n] = p
    return names


def _placeholder(word: str) -> bool:
    """RUN, NAME, [RUN...], RUN_B, ID, 'EXP', <x>, a|b: words that stand for something."""
    bare = word.strip("[](){}.,'\"<>")
    return not bare or bare.upper() == bare or "|" in word or "..." in word or "<" in word


def problems(cmd: DocCommand, experiments: set[str]) -> list[str]:
    """What in ``cmd`` the command tree does not have: an unknown verb, option or literal choice."""
    out: list[str] = []
    command: click.Command = cli
    path: list[str] = []
    positional: list[str] = []
    words = [w.strip("[]") if w.startswith("[") or w.endswith("]") else w for w in cmd.args]
    i = 0
    while i < len(words):
        w = words[i]
        i += 1
        if not w:
            continue
        if w == "--":
            break
        if w.startswith("-") and len(w) > 1 and not re.match(r"^-\d", w):
            name, _, inline = w.partition("=")
            options = _option_names(command)
            if name not in options:
                out.append(f"'{' '.join(['enginebench', *path])}' has no option {name}")
                continue
            opt = options[name]
            if opt is None or opt.is_flag or opt.count:
                continue
            value = inline or (words[i] if i < len(words) else "")
            if not inline:
                i += 1
            if isinstance(opt.type, click.Choice) and value and not _placeholder(value) \
                    and value not in opt.type.choices:
                out.append(f"{name} {value!r} of 'enginebench {' '.join(path)}' is not one of "
                           f"{', '.join(map(str, opt.type.choices))}")
            continue
        if isinstance(command, click.Group) and not positional:
            sub = command.commands.get(w)
            if sub is None:
                if not _placeholder(w):
                    out.append(f"'{' '.join(['enginebench', *path])}' has no subcommand {w!r}")
                return out
            command, path = sub, [*path, w]
            continue
        positional.append(w)
    if tuple(path) in EXPERIMENT_VERBS and positional:
        exp = positional[0]
        literal = not _placeholder(exp) and not exp.endswith(".toml") and "/" not in exp
        if literal and exp not in experiments:
            out.append(f"'enginebench {' '.join(path)}': no built-in experiment {exp!r}")
    return out


COMMANDS = doc_commands()


def test_the_docs_hold_commands_to_check():
    """The extraction works: the README's usage block alone holds about twenty commands."""
    readme = [c for c in COMMANDS if c.where.startswith("README.md")]
    assert len(readme) >= 15 and len(COMMANDS) >= 40
    assert any(c.args[:2] == ("run", "--resume") for c in readme)


@pytest.mark.parametrize("cmd", COMMANDS, ids=[f"{c.where} {' '.join(c.args[:2])}" for c in COMMANDS])
def test_every_documented_command_exists(cmd: DocCommand):
    from enginebench.experiments.spec import builtin_names

    assert problems(cmd, set(builtin_names())) == [], f"{cmd.where}: {cmd.text}"


def test_the_checker_finds_an_unknown_verb_option_choice_and_experiment():
    fake = [DocCommand("x", "", tuple(shlex.split(text))) for text in (
        "tables latest", "table latest --colour", "table latest --format pdf", "run no-such-experiment -j 2",
        "runs list --tag owner=ana", "compare RUN_A RUN_B [RUN_C ...]", "export RUN --mlflow URI [--artifacts DIR]")]
    found = [problems(c, {"marine-diesel-egt-quick"}) for c in fake]
    assert [len(f) for f in found] == [1, 1, 1, 1, 0, 0, 0], found
