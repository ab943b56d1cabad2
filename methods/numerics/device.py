"""Where torch-based solvers run: one resolver for every method's ``device`` option, and a CPU thread cap."""

from __future__ import annotations

from contextlib import contextmanager
from typing import TYPE_CHECKING, Iterator

from enginebench.errors import MethodError

if TYPE_CHECKING:  # imported in the functions: the method modules that import these load without torch
    import torch


def resolve_device(device: str, who: str) -> torch.device:
    """``"auto"`` -> CUDA when available, else CPU; other names (``cpu``, ``cuda``, ``cuda:1``) are checked to exist.

    ``who`` opens every error line (e.g. "method 'moe'", "FALKON solver"), so the message says
    which option of which method to change.
    """
    import torch

    if not isinstance(device, str):
        raise MethodError(f"{who}: device must be a string ('auto', 'cpu', 'cuda', 'cuda:0'), got {device!r}")
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, ValueError):
        raise MethodError(f"{who}: unknown device {device!r}; use 'auto', 'cpu' or 'cuda[:index]'") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise MethodError(f"{who}: device {device!r} requested but CUDA is not available; use device='auto' or 'cpu'")
    if dev.type not in ("cpu", "cuda"):
        raise MethodError(f"{who}: device {device!r} is not supported; use 'auto', 'cpu' or 'cuda[:index]'")
    return dev


@contextmanager
def cpu_threads(limit: int | None, device: torch.device) -> Iterator[None]:
    """Cap torch's intra-op threads on CPU for the duration, then restore them.

    Small networks gain nothing from per-op thread fan-out and, on busy shared cores,
    each synchronised reduction can stall for a scheduler quantum; parallelism belongs
    to the runner's process pool. ``None`` leaves the setting alone.
    """
    import torch

    before = torch.get_num_threads()
    if limit is None or device.type != "cpu" or limit >= before:
        yield
        return
    torch.set_num_threads(limit)
    try:
        yield
    finally:
        torch.set_num_threads(before)
