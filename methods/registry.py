"""Finding methods: built-ins and installed plugins via entry points, and plugin files."""

from __future__ import annotations

import importlib.util
import sys
from importlib.metadata import entry_points
from pathlib import Path

from enginebench.errors import MethodError
from enginebench.methods.base import FAMILIES, Method

ENTRY_POINT_GROUP = "enginebench.methods"

_extra: dict[str, type[Method]] = {}


def _check_class(obj: object, origin: str) -> type[Method]:
    if not (isinstance(obj, type) and issubclass(obj, Method)):
        raise MethodError(f"{origin}: {obj!r} is not a subclass of enginebench.methods.base.Method")
    if not obj.name:
        raise MethodError(f"{origin}: method class {obj.__name__} has no 'name'")
    if obj.family not in FAMILIES:
        raise MethodError(f"{origin}: method {obj.name!r} has family {obj.family!r}; use one of {', '.join(FAMILIES)}")
    return obj


def register(cls: type[Method]) -> type[Method]:
    """Register a method class for this process (usable as a decorator)."""
    _extra[_check_class(cls, "register").name] = cls
    return cls


def load_plugin_file(path: str | Path) -> list[type[Method]]:
    """Import a Python file and register every Method subclass it defines."""
    path = Path(path)
    if not path.is_file():
        raise MethodError(f"plugin file {path} does not exist")
    mod_name = f"enginebench_plugin_{path.stem}"
    spec = importlib.util.spec_from_file_location(mod_name, path)
    if spec is None or spec.loader is None:
        raise MethodError(f"plugin file {path} cannot be imported")
    module = importlib.util.module_from_spec(spec)
    sys.modules[mod_name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as exc:  # a plugin's own error, reported as one line
        raise MethodError(f"plugin file {path}: {type(exc).__name__}: {exc}") from exc
    found = [
        obj for obj in vars(module).values()
        if isinstance(obj, type) and issubclass(obj, Method) and obj is not Method and obj.__module__ == mod_name and obj.name
    ]
    if not found:
        raise MethodError(f"plugin file {path} defines no Method subclass with a name")
    for cls in found:
        register(cls)
    return found


def available() -> dict[str, type[Method]]:
    """Every method known to this process: entry points first, then registered classes."""
    found: dict[str, type[Method]] = {}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            cls = ep.load()
        except Exception as exc:
            raise MethodError(f"entry point {ep.name!r} ({ep.value}) failed to load: {exc}") from exc
        found[ep.name] = _check_class(cls, f"entry point {ep.name!r}")
    found.update(_extra)
    return dict(sorted(found.items()))


def get(name: str) -> type[Method]:
    methods = available()
    if name not in methods:
        raise MethodError(f"unknown method {name!r}; available: {', '.join(methods)} (or pass --plugin FILE.py)")
    return methods[name]
