"""enginebench: benchmark physical, data-driven and hybrid engine models under one protocol.

Method authors (plugins) import from ``enginebench.api``, the stable public surface. From a notebook,
``enginebench.run``, ``enginebench.open_run``, ``enginebench.Run`` and ``enginebench.EngineBenchError``
(docs/python.md) are here too, loaded on first use so that ``import enginebench`` stays light.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("enginebench")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"

__all__ = ["EngineBenchError", "Run", "__version__", "open_run", "run"]

_API = ("EngineBenchError", "Run", "open_run", "run")


def __getattr__(name: str):
    """``enginebench.run`` and friends from ``enginebench.api``, imported on first use (PEP 562)."""
    if name in _API:
        from enginebench import api

        return getattr(api, name)
    raise AttributeError(f"module 'enginebench' has no attribute {name!r}")
