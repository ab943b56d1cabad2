"""Declared configuration: typed fields with a meaning, checked in one place.

Method options, the experiment spec's tables, the import spec and baseline files
declare their keys once as :class:`Field` s collected in a :class:`Declaration`; the
declaration gives the defaults, checks a mapping (one error line naming where, the key,
the value and what it must be; unknown keys get a "did you mean") and prints itself as
rows (name, type, default, unit, meaning) for ``enginebench methods show``.

A declaration reads as one line per key, through the small constructors::

    Declaration(
        flag("standardize", True, "scale each feature to zero mean and unit variance"),
        whole("centres", 2000, "Nystroem centres of the FALKON solver", low=1),
        log_grid("gamma_grid", (-4, 4, 41), "kernel width searched, log10 of gamma", searches="gamma"),
    )

Booleans are never numbers (``true`` is refused where a number is expected).
"""

from __future__ import annotations

import difflib
import json
import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Iterator, Mapping, Sequence

import numpy as np

KINDS = ("bool", "int", "float", "str", "choice", "log_grid", "list", "table", "any")
EDGES = ("both", "low", "high", "none")
"""Grid edges at which a selected value is worth a warning (an integer degree's lower edge 1 is not)."""

MAX_GRID_COUNT = 10_000
"""The most values one log grid may hold (a grid of 10^7 points is a typo, not a search)."""
LOG_GRID_MUST = ("must be (low exponent, high exponent, count) with 1 <= count <= 10000, e.g. (-4, 4, 41) for "
                 "10^-4 ... 10^4")


class Invalid(ValueError):
    """A value a field refuses. ``template`` is the message body: ``{name}`` and ``{value}`` are
    replaced by the key as the caller names it and the value's repr (no other braces are read)."""

    def __init__(self, template: str) -> None:
        super().__init__(template)
        self.template = template

    def render(self, name: str, value: Any) -> str:
        return self.template.replace("{name}", name).replace("{value}", repr(value))


def is_number(value: Any) -> bool:
    """An int or float (numpy's too), never a boolean."""
    return not isinstance(value, (bool, np.bool_)) and isinstance(value, (int, float, np.integer, np.floating))


def is_whole(value: Any) -> bool:
    """An integer (numpy's too), never a boolean or a float."""
    return not isinstance(value, (bool, np.bool_)) and isinstance(value, (int, np.integer))


@dataclass(frozen=True)
class Field:
    """One declared key: its default, kind, accepted values, unit and a one-line meaning."""

    name: str
    default: Any
    meaning: str
    kind: str = "any"
    choices: tuple[Any, ...] = ()
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    """True: ``low`` itself is refused (``> low``); False: ``>= low``."""
    high_open: bool = False
    unit: str = ""
    nullable: bool = False
    """None is accepted (the meaning says what None does)."""
    items: str | None = None
    min_items: int = 1
    """A list's least length."""
    """A list's item kind ("int", "float", "str"), checked with the field's bounds; None: anything."""
    searches: tuple[str, ...] = ()
    """Hyperparameters whose searched grid this option sets (``grid_edges``)."""
    edges: str = "both"
    bound: tuple[float | None, float | None] = (None, None)
    """Hard bounds of the searched values (``searches``), in the hyperparameter's own units: a value selected
    at an edge of its grid is searched further that way (``experiments/extension.py``), never past these;
    None on a side: not extended that way (the edge warning then says to widen the grid)."""
    message: str = ""
    """Replaces the generated refusal (an :class:`Invalid` template: ``{name}``, ``{value}``)."""
    type_label: str = ""
    """Replaces the generated type column of ``rows`` (for keys checked by ``check``)."""
    check: Callable[[Any], Any] | None = None
    """Extra check after the kind's: returns the value (normalised) or raises :class:`Invalid`."""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"field {self.name!r}: kind {self.kind!r} is not one of {', '.join(KINDS)}")
        if self.edges not in EDGES:
            raise ValueError(f"field {self.name!r}: edges {self.edges!r} is not one of {', '.join(EDGES)}")
        lo, hi = self.bound
        if lo is not None and hi is not None and not lo < hi:
            raise ValueError(f"field {self.name!r}: bound {self.bound!r} must be (low, high) with low < high")

    # -- describing ---------------------------------------------------------------------------
    def bounds(self) -> str:
        """'>= 1', '> 0', 'in (0, 1)', or '' without bounds."""
        lo, hi = self.low, self.high
        if lo is not None and hi is not None:
            return f"in {'(' if self.low_open else '['}{lo:g}, {hi:g}{')' if self.high_open else ']'}"
        if lo is not None:
            return f"{'>' if self.low_open else '>='} {lo:g}"
        if hi is not None:
            return f"{'<' if self.high_open else '<='} {hi:g}"
        return ""

    def what(self) -> str:
        """What a value must be, in words ("a whole number >= 1", "a positive number")."""
        b = self.bounds()
        if self.kind == "int":
            text = f"a whole number {b}".rstrip()
        elif self.kind == "float":
            text = "a positive number" if b == "> 0" else f"a number {b}".rstrip()
        elif self.kind == "bool":
            text = "true or false"
        elif self.kind == "str":
            text = "a non-empty string"
        elif self.kind == "choice":
            text = _alternatives(self.choices)
        elif self.kind == "log_grid":
            text = "(low exponent, high exponent, count) with 1 <= count <= 10000"
        elif self.kind == "list":
            item = {"int": "whole numbers", "float": "numbers", "str": "names"}.get(self.items or "", "")
            text = f"a {'non-empty ' if self.min_items else ''}list{f' of {item}' if item else ''}{f' {b}' if b and item else ''}"
        elif self.kind == "table":
            text = "a table of name = value"
        else:
            text = "any value"
        return f"{text} or None" if self.nullable and self.kind != "any" else text

    def type_text(self) -> str:
        """The type column of ``rows``: kind with its range or choices."""
        if self.type_label:
            return self.type_label
        if self.kind == "choice":
            text = "choice: " + " | ".join(map(str, self.choices))
        elif self.kind in ("int", "float") and self.bounds():
            text = f"{self.kind} {self.bounds()}"
        elif self.kind == "list" and self.items:
            text = f"list[{self.items}]" + (f" {self.bounds()}" if self.bounds() else "")
        else:
            text = self.kind
        return f"{text} | None" if self.nullable and self.kind != "any" else text

    # -- checking -----------------------------------------------------------------------------
    def validate(self, value: Any) -> Any:
        """The value checked (numpy scalars made plain); :class:`Invalid` otherwise."""
        if value is None and (self.nullable or self.kind == "any"):
            return None
        value = self._kind(value)
        return self.check(value) if self.check is not None else value

    def _refuse(self, template: str) -> Invalid:
        return Invalid(self.message or template)

    def _kind(self, value: Any) -> Any:
        k = self.kind
        if k == "any":
            return value
        if k == "bool":
            if not isinstance(value, (bool, np.bool_)):
                raise self._refuse("{name} must be " + self.what() + ", got {value}")
            return bool(value)
        if k == "choice":
            if isinstance(value, (list, dict, np.ndarray)) or value not in self.choices \
                    or isinstance(value, bool) != any(isinstance(c, bool) for c in self.choices if c == value):
                raise self._refuse("{name}={value}; use " + self.what())
            return value
        if k == "log_grid":
            try:
                low, high, num = value
                ok = (all(is_number(v) for v in (low, high, num)) and math.isfinite(low) and math.isfinite(high)
                      and math.isfinite(num) and float(num) == int(num) and 1 <= int(num) <= MAX_GRID_COUNT)
            except (TypeError, ValueError, OverflowError):
                ok = False
            if not ok:
                raise self._refuse("{name}={value} " + LOG_GRID_MUST)
            return value
        if k == "list":
            if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, (list, tuple, np.ndarray)) \
                    or len(value) < self.min_items or not all(self._item_ok(v) for v in value):
                raise self._refuse("{name} must be " + self.what() + ", got {value}")
            return value
        if k == "table":
            if not isinstance(value, Mapping):
                raise self._refuse("{name} must be " + self.what() + ", got {value}")
            return value
        if k == "str":
            if not isinstance(value, str) or not value.strip():
                raise self._refuse("{name} must be " + self.what() + ", got {value}")
            return value
        if not self._item_ok(value, k):
            raise self._refuse("{name} must be " + self.what() + ", got {value}")
        return int(value) if k == "int" else value.item() if isinstance(value, np.generic) else value

    def _item_ok(self, v: Any, kind: str | None = None) -> bool:
        kind = kind or self.items
        if kind is None:
            return True
        if kind == "str":
            return isinstance(v, str) and bool(v.strip())
        if not (is_whole(v) if kind == "int" else is_number(v) and math.isfinite(v)):
            return False
        lo_ok = self.low is None or (v > self.low if self.low_open else v >= self.low)
        hi_ok = self.high is None or (v < self.high if self.high_open else v <= self.high)
        return lo_ok and hi_ok


def _alternatives(choices: Sequence[Any]) -> str:
    words = [repr(c) for c in choices]
    return " or ".join(words) if len(words) <= 2 else "one of " + ", ".join(words)


# -- constructors: one line per key ---------------------------------------------------------------
def flag(name: str, default: bool, meaning: str, **kw: Any) -> Field:
    """A true/false switch."""
    return Field(name, default, meaning, kind="bool", **kw)


def whole(name: str, default: int | None, meaning: str, low: int | None = None, high: int | None = None,
          **kw: Any) -> Field:
    """A whole number (not a boolean, not a float) within [low, high]."""
    return Field(name, default, meaning, kind="int", low=low, high=high, **kw)


def number(name: str, default: float | None, meaning: str, low: float | None = None, high: float | None = None,
           **kw: Any) -> Field:
    """A finite number within the bounds (``low_open``/``high_open`` exclude them)."""
    return Field(name, default, meaning, kind="float", low=low, high=high, **kw)


def positive(name: str, default: float | None, meaning: str, **kw: Any) -> Field:
    """A finite number > 0."""
    return Field(name, default, meaning, kind="float", low=0, low_open=True, **kw)


def choice(name: str, default: Any, meaning: str, choices: Sequence[Any], **kw: Any) -> Field:
    """One of a fixed set of values."""
    return Field(name, default, meaning, kind="choice", choices=tuple(choices), **kw)


def log_grid(name: str, default: tuple[float, float, int], meaning: str, **kw: Any) -> Field:
    """A (low exponent, high exponent, count) grid of 10**low ... 10**high."""
    return Field(name, default, meaning, kind="log_grid", **kw)


def listing(name: str, default: Any, meaning: str, items: str | None = None, **kw: Any) -> Field:
    """A non-empty list (of ``items``: "int", "float" or "str", within the bounds)."""
    return Field(name, default, meaning, kind="list", items=items, **kw)


def text(name: str, default: str | None, meaning: str, **kw: Any) -> Field:
    """A non-empty string."""
    return Field(name, default, meaning, kind="str", **kw)


def table(name: str, default: Any, meaning: str, **kw: Any) -> Field:
    """A table (mapping) of name = value."""
    return Field(name, default, meaning, kind="table", **kw)


def anything(name: str, default: Any, meaning: str = "", **kw: Any) -> Field:
    """A value of any type (checked, if at all, by ``check`` or by its user)."""
    return Field(name, default, meaning, kind="any", **kw)


# -- the collection -------------------------------------------------------------------------------
def did_you_mean(key: str, known: Sequence[str]) -> str:
    """" (did you mean 'x'?)" for the closest known key, or ""."""
    close = difflib.get_close_matches(key, list(known), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


@dataclass(frozen=True)
class Declaration:
    """An ordered set of fields: defaults, checks and printable rows."""

    fields: tuple[Field, ...] = ()
    by_name: dict[str, Field] = field(init=False, repr=False, compare=False)

    def __init__(self, *fields: Field) -> None:
        names = [f.name for f in fields]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise ValueError(f"field(s) declared twice: {', '.join(twice)}")
        object.__setattr__(self, "fields", tuple(fields))
        object.__setattr__(self, "by_name", {f.name: f for f in fields})

    def __iter__(self) -> Iterator[Field]:
        return iter(self.fields)

    def __contains__(self, name: object) -> bool:
        return name in self.by_name

    def __getitem__(self, name: str) -> Field:
        return self.by_name[name]

    def names(self) -> list[str]:
        return [f.name for f in self.fields]

    def defaults(self) -> dict[str, Any]:
        """Every key with its default."""
        return {f.name: f.default for f in self.fields}

    def extend(self, *fields: Field) -> "Declaration":
        """These fields added; one with a declared name replaces that field in place."""
        new = {f.name: f for f in fields}
        kept = [new.pop(f.name, f) for f in self.fields]
        return Declaration(*kept, *new.values())

    def with_defaults(self, **defaults: Any) -> "Declaration":
        """The same fields with other defaults (keys must be declared)."""
        unknown = set(defaults) - set(self.by_name)
        if unknown:
            raise ValueError(f"not declared: {', '.join(sorted(unknown))}")
        return Declaration(*(replace(f, default=defaults[f.name]) if f.name in defaults else f for f in self.fields))

    def unknown(self, keys: Sequence[str] | set[str], noun: str = "option(s)", known_label: str = "known") -> str | None:
        """'unknown option(s) a (did you mean 'b'?); known: ...' or None when every key is declared."""
        extra = sorted(set(keys) - set(self.by_name))
        if not extra:
            return None
        parts = [k + did_you_mean(k, self.names()) for k in extra]
        return f"unknown {noun} {', '.join(parts)}; {known_label}: {', '.join(sorted(self.by_name)) or 'none'}"

    def validate(self, values: Mapping[str, Any], where: str, error: Callable[[str], Exception],
                 name: str = "option {key}", fill: bool = True, unknown_noun: str = "option(s)",
                 known_label: str = "known", strict: bool = True) -> dict[str, Any]:
        """The checked values (defaults filled in when ``fill``); ``error(line)`` raised for the first problem.

        ``where`` starts each line ("method 'krls'", a file path; "" for none) and ``name``
        names a key in it ("option {key}", "[split] {key}", "key {key!r}"). Undeclared keys
        are refused unless ``strict`` is false (then they pass through unchecked).
        """
        prefix = f"{where}: " if where else ""
        problem = self.unknown(list(values), unknown_noun, known_label) if strict else None
        if problem:
            raise error(prefix + problem)
        out = self.defaults() if fill else {}
        for key, value in values.items():
            f = self.by_name.get(key)
            if f is None:
                out[key] = value
                continue
            try:
                out[key] = f.validate(value)
            except Invalid as bad:
                raise error(prefix + bad.render(name.format(key=key), value)) from None
        return out

    def rows(self) -> list[tuple[str, str, str, str, str]]:
        """(name, type, default, unit, meaning) per field, for printing (a searched grid's hard bounds appended)."""
        return [(f.name, f.type_text(), _shown(f.default), f.unit, f.meaning + _bound_text(f)) for f in self.fields]

    def edges(self) -> dict[str, str]:
        """Searched hyperparameter -> grid edges worth a warning, from the fields that set a grid."""
        return {param: f.edges for f in self.fields for param in f.searches}

    def bounds(self) -> dict[str, tuple[float | None, float | None]]:
        """Searched hyperparameter -> its declared hard bounds (low, high), for those that declare one."""
        return {param: f.bound for f in self.fields for param in f.searches if f.bound != (None, None)}


def _bound_text(f: Field) -> str:
    lo, hi = f.bound
    if (lo, hi) == (None, None) or not f.searches:
        return ""
    side = [f">= {lo:g}" if lo is not None else "", f"<= {hi:g}" if hi is not None else ""]
    return f"; extended at its edges, {' and '.join(s for s in side if s)} ({', '.join(f.searches)})"


def _shown(value: Any) -> str:
    if value is None:
        return "None"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    return str(list(value)) if isinstance(value, tuple) else str(value)
