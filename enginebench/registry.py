"""Finding methods: built-ins and installed plugins via entry points, and plugin files.

Rules that keep a table honest about which code made it:

* a plugin file is imported in full or not at all: anything it raises at import
  (``SystemExit`` included) is one ``MethodError`` naming the file and the exception;
* a class may not take a name that is already registered by other code (a built-in,
  an installed plugin, another plugin file) unless it says so with the class attribute
  ``overrides = True``; loading the same file again (or registering the same class) is
  not shadowing;
* every plugin file loaded is remembered with its path and SHA-256, and which method
  names it provides, so a run can record them and a resumed or reported run can be
  checked against them (``plugin_origin``, ``plugin_records``, ``plugin_mismatches``);
* an installed plugin whose entry point fails to load is listed by ``broken()`` with
  its reason and is refused by name in ``get``; it does not stop every other command.
  ``get(name)`` imports that name's entry point only (plugins load when asked for);
  ``available()`` and ``broken()``, for listings, import them all.
"""

from __future__ import annotations

import hashlib
import importlib.util
import sys
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Iterable

from enginebench.errors import MethodError
from enginebench.method import FAMILIES, Method

ENTRY_POINT_GROUP = "enginebench.methods"

_extra: dict[str, type[Method]] = {}
_origin: dict[str, tuple[str, str]] = {}
"""Method name -> (plugin file, its SHA-256) for the classes registered from plugin files."""


def _check_class(obj: object, origin: str) -> type[Method]:
    if not (isinstance(obj, type) and issubclass(obj, Method)):
        raise MethodError(f"{origin}: {obj!r} is not a subclass of enginebench.method.Method")
    if not obj.name:
        raise MethodError(f"{origin}: method class {obj.__name__} has no 'name'")
    if obj.family not in FAMILIES:
        raise MethodError(f"{origin}: method {obj.name!r} has family {obj.family!r}; use one of {', '.join(FAMILIES)}")
    return obj


def _reason(exc: BaseException) -> str:
    """An exception as ``Type: message`` on one line."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _load(ep: Any) -> tuple[type[Method] | None, str | None]:
    """Import one entry point: (its class, None), or (None, why it is broken, one line)."""
    try:
        return _check_class(ep.load(), f"entry point {ep.name!r}"), None
    except KeyboardInterrupt:
        raise
    except MethodError as exc:
        return None, f"entry point {ep.name} = {ep.value}: {exc}"
    except BaseException as exc:  # SystemExit too: a broken package must not end the command
        return None, f"entry point {ep.name} = {ep.value} failed to load: {_reason(exc)}"


def _entry_points(name: str | None = None) -> tuple[dict[str, type[Method]], dict[str, str]]:
    """(loaded classes, broken entry points with their reason), by entry-point name.

    With ``name`` only the entry points of that name are imported: asking for one method
    never imports (or trips over) another package.
    """
    found: dict[str, type[Method]] = {}
    broken: dict[str, str] = {}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if name is not None and ep.name != name:
            continue
        cls, why = _load(ep)
        if cls is not None:
            found[ep.name] = cls
        else:
            broken[ep.name] = why
    return found, broken


def _describe(name: str, cls: type[Method]) -> str:
    """Where the class registered as ``name`` comes from, for messages."""
    if name in _origin and _extra.get(name) is cls:
        return f"plugin file {_origin[name][0]}"
    return f"{cls.__module__}.{cls.__qualname__}"


def _same_code(old: type[Method], new: type[Method], old_file: str | None, new_file: str | None) -> bool:
    """Registering ``new`` where ``old`` is: the same class, or the same file or module loaded again."""
    if old is new:
        return True
    if new_file is not None:
        return old_file == new_file
    return old_file is None and (old.__module__, old.__qualname__) == (new.__module__, new.__qualname__)


def _register(cls: type[Method], origin: str, plugin: tuple[str, str] | None = None) -> type[Method]:
    cls = _check_class(cls, origin)
    name = cls.name
    if name in _extra:
        existing = _extra[name]
    else:
        existing = _entry_points(name)[0].get(name)
    if existing is not None and not getattr(cls, "overrides", False):
        old_file = _origin[name][0] if name in _origin and _extra.get(name) is existing else None
        if not _same_code(existing, cls, old_file, plugin[0] if plugin else None):
            raise MethodError(
                f"{origin}: class {cls.__name__} takes the name {name!r}, already registered by {_describe(name, existing)}; "
                f"rename it, or set overrides = True in the class to replace {name!r} on purpose"
            )
    _extra[name] = cls
    if plugin is None:
        _origin.pop(name, None)
    else:
        _origin[name] = plugin
    return cls


def register(cls: type[Method]) -> type[Method]:
    """Register a method class for this process (usable as a decorator); see the module docstring on names."""
    return _register(cls, "register")


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes (hex)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def load_plugin_file(path: str | Path) -> list[type[Method]]:
    """Import a Python file and register every Method subclass it defines (MethodError on any failure)."""
    path = Path(path)
    if not path.is_file():
        raise MethodError(f"plugin file {path} does not exist")
    try:
        digest = file_sha256(path)
    except OSError as exc:
        raise MethodError(f"plugin file {path} cannot be read ({exc.strerror or exc})") from None
    mod_name = f"enginebench_plugin_{path.stem}"
    spec = importlib.util.spec_from_file_location(mod_name, path)
    if spec is None or spec.loader is None:
        raise MethodError(f"plugin file {path} cannot be imported (is it a .py file?)")
    module = importlib.util.module_from_spec(spec)
    previous = sys.modules.get(mod_name)
    sys.modules[mod_name] = module
    try:
        spec.loader.exec_module(module)
    except KeyboardInterrupt:
        raise
    except BaseException as exc:  # SystemExit included: a plugin's own error, reported as one line
        if previous is None:
            sys.modules.pop(mod_name, None)
        else:
            sys.modules[mod_name] = previous
        raise MethodError(f"plugin file {path}: {_reason(exc)} (raised while importing it); fix the plugin") from None
    found = [
        obj for obj in vars(module).values()
        if isinstance(obj, type) and issubclass(obj, Method) and obj is not Method and obj.__module__ == mod_name and obj.name
    ]
    if not found:
        raise MethodError(f"plugin file {path} defines no Method subclass with a name")
    resolved = str(path.resolve())
    for cls in found:
        _register(cls, f"plugin file {path}", (resolved, digest))
    return found


def plugin_origin(name: str) -> tuple[str, str] | None:
    """(plugin file, SHA-256 at loading) of the class registered as ``name``, or None for other code."""
    return _origin.get(name) if name in _extra else None


def plugin_records(methods: Iterable[str]) -> list[dict[str, Any]]:
    """What a run records of its plugin files: ``[{"path", "sha256", "methods"}]`` for the given methods."""
    files: dict[tuple[str, str], list[str]] = {}
    for name in methods:
        origin = plugin_origin(name)
        if origin is not None:
            files.setdefault(origin, []).append(name)
    return [{"path": p, "sha256": h, "methods": sorted(m)} for (p, h), m in sorted(files.items())]


def plugin_mismatches(recorded: list[dict[str, Any]], methods: Iterable[str]) -> list[str]:
    """How the plugin files in this process differ from those a run recorded, one phrase per problem.

    For each of the run's methods: the same plugin file content (its path may have moved)
    must provide it as when the run was made, or no plugin when the run used other code.
    """
    used: dict[str, tuple[str, str]] = {}
    for rec in recorded:
        for name in rec.get("methods", []):
            used[str(name)] = (str(rec.get("path")), str(rec.get("sha256")))
    problems: list[str] = []
    for name in methods:
        then, now = used.get(name), plugin_origin(name)
        if then is None and now is None:
            continue
        if then is None:
            problems.append(f"method {name!r} now comes from plugin file {now[0]}, the run used the registered one: drop that --plugin")
            continue
        path, digest = then
        if now is not None and now[1] == digest:
            continue
        if now is not None:
            problems.append(f"method {name!r} comes from plugin file {now[0]} (sha256 {now[1][:12]}), the run used {path} "
                            f"(sha256 {digest[:12]})")
        elif not Path(path).is_file():
            problems.append(f"plugin file {path} (method {name!r}) is absent")
        else:
            current = file_sha256(path)
            if current != digest:
                problems.append(f"plugin file {path} (method {name!r}) changed since the run (sha256 {digest[:12]} then, "
                                f"{current[:12]} now)")
            else:
                problems.append(f"plugin file {path} (method {name!r}) is not loaded: pass --plugin {path}")
    return problems


def available() -> dict[str, type[Method]]:
    """Every method known to this process: entry points first, then registered classes (broken ones left out)."""
    found = _entry_points()[0]
    found.update(_extra)
    return dict(sorted(found.items()))


def broken() -> dict[str, str]:
    """Installed plugins whose entry point failed to load: name -> why (one line)."""
    return {k: v for k, v in _entry_points()[1].items() if k not in _extra}


def get(name: str) -> type[Method]:
    """The class registered as ``name``; MethodError naming the alternatives (or why an installed one is broken)."""
    if name in _extra:
        return _extra[name]
    found, bad = _entry_points(name)  # only this name's entry point is imported
    if name in found:
        return found[name]
    if name in bad:
        raise MethodError(f"method {name!r} cannot be used: {bad[name]}; reinstall or fix that package")
    names = {ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)}  # names only: nothing more is imported
    methods = sorted(names | set(_extra))
    raise MethodError(f"unknown method {name!r}; available: {', '.join(methods)} (or pass --plugin FILE.py)")
