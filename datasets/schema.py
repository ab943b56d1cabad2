"""Column roles and units: what each signal of a dataset is and how it may be used."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

from enginebench.errors import DataError

ROLES = ("input", "output", "internal", "group")
"""input: exogenous signal available at run time; output: a target; internal: measured
only in a test campaign (training surrogates, never a run-time input); group: a key such
as engine or flight id that splits keep on one side."""


@dataclass(frozen=True)
class Column:
    """One signal column: its name, role and unit."""

    name: str
    role: str
    unit: str = ""

    def __post_init__(self) -> None:
        if self.role not in ROLES:
            raise DataError(
                f"column {self.name!r}: unknown role {self.role!r}; use one of {', '.join(ROLES)}"
            )


@dataclass(frozen=True)
class Schema:
    """The ordered columns of a dataset (the time and segment columns are implicit)."""

    columns: tuple[Column, ...]

    def __post_init__(self) -> None:
        seen: set[str] = set()
        for c in self.columns:
            if c.name in seen:
                raise DataError(f"column {c.name!r} is declared twice")
            seen.add(c.name)

    @classmethod
    def from_roles(cls, roles: dict[str, str], units: dict[str, str] | None = None) -> "Schema":
        units = units or {}
        return cls(tuple(Column(n, r, units.get(n, "")) for n, r in roles.items()))

    def names(self, role: str | None = None) -> list[str]:
        return [c.name for c in self.columns if role is None or c.role == role]

    def __getitem__(self, name: str) -> Column:
        for c in self.columns:
            if c.name == name:
                return c
        raise DataError(f"no column {name!r}; known columns: {', '.join(self.names())}")

    def __contains__(self, name: object) -> bool:
        return any(c.name == name for c in self.columns)

    @property
    def inputs(self) -> list[str]:
        return self.names("input")

    @property
    def outputs(self) -> list[str]:
        return self.names("output")

    @property
    def internals(self) -> list[str]:
        return self.names("internal")

    @property
    def groups(self) -> list[str]:
        return self.names("group")

    def with_roles(self, changes: dict[str, str]) -> "Schema":
        """A copy with some columns given new roles (e.g. choose which outputs are targets)."""
        for n in changes:
            self[n]  # raises with the list of known columns
        return Schema(tuple(Column(c.name, changes.get(c.name, c.role), c.unit) for c in self.columns))

    def select(self, names: Iterable[str]) -> "Schema":
        keep = set(names)
        return Schema(tuple(c for c in self.columns if c.name in keep))

    def to_dict(self) -> dict[str, dict[str, str]]:
        return {c.name: {"role": c.role, "unit": c.unit} for c in self.columns}

    @classmethod
    def from_dict(cls, d: dict[str, dict[str, str]]) -> "Schema":
        return cls(tuple(Column(n, v["role"], v.get("unit", "")) for n, v in d.items()))
