"""enginebench: benchmark physical, data-driven and hybrid engine models under one protocol.

Method authors (plugins) import from ``enginebench.api``, the stable public surface.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("enginebench")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
