"""Errors that reach the user as one readable line (exit code 2), never a traceback."""

from __future__ import annotations


class EngineBenchError(Exception):
    """Bad input or an impossible request: the message says what, where and what to do."""

    exit_code = 2


class DataError(EngineBenchError):
    """A dataset, file or column that cannot be used as given."""


class SpecError(EngineBenchError):
    """An experiment or import spec (TOML) that is malformed or inconsistent."""


class MethodError(EngineBenchError):
    """A method that cannot be found, configured or applied."""


class StoreError(EngineBenchError):
    """A run store or run that is missing, locked or damaged."""
