"""The papers the project implements, under stable names (not "seed 000": a seed is a random seed).

One place maps each paper's stable name to its title, what the project takes from it and
the old "seed NNN" label, so the command line (``layout --paper``, ``calibrate pm --fat``),
the shipped literature tables and docs/papers.md all say the same thing. The old labels
stay accepted as deprecated aliases, each answered with one ``note:`` line.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Paper:
    """A source paper: stable ``name``, old ``legacy`` label, ``title`` and what the project uses."""

    name: str
    legacy: str
    title: str
    uses: str
    method_order: tuple[str, ...] = ()
    """The rows of the paper's result tables, in its order (``layout --paper``); other methods follow."""


PAPERS: dict[str, Paper] = {p.name: p for p in (
    Paper("egt-hybrid", "seed 000",
          "Physical, data-driven and hybrid approaches to model engine exhaust gas temperatures in operational conditions",
          "the marine-diesel case: PM, KRLS and MTL-KRLS, Table 4 (FAT calibration), Tables 8-9 (layout)",
          ("naive-mean", "pm", "krls", "mtl-krls")),
    Paper("hil-diesel", "seed 001",
          "Modeling and validation of a diesel engine with turbocharger for hardware-in-the-loop applications",
          "the block structure of the synthetic marine 'true engine' and its weighted least-squares tuning"),
    Paper("marine-twin", "seed 002",
          "Towards a digital twin of a mid-speed marine engine: from detailed 1D engine model to real-time "
          "implementation on a target platform",
          "the speed/accuracy trade-off of fast-running models and their 5 % tolerances"),
    Paper("turboshaft-moe", "seed 003", "Helicopter turboshaft modeling via mixtures of experts",
          "the turboshaft case: MoE, SINDy, NFIR and cascades, Tables 2-3 (layout)",
          ("nfir", "moe", "sindy", "moe[ideal]", "sindy[ideal]", "moe-nfir", "sindy-nfir", "moe-moe")),
)}

LAYOUT_PAPERS = ("turboshaft-moe", "egt-hybrid")
"""Papers whose result tables ``enginebench layout --paper`` reproduces."""

LEGACY_FLAGS = {"seed003": "turboshaft-moe", "seed000": "egt-hybrid"}
"""Old ``layout`` flags (``--seed003``) -> stable name."""


def deprecated(old: str, new: str) -> str:
    """The one ``note:`` line printed when an old spelling is used."""
    return f"note: {old} is deprecated (a seed is a random seed); use {new}"
