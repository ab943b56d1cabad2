"""What a run's jobs said, as lines for people: each failure reason and warning once, with its count."""

from __future__ import annotations


def note_lines(notes: dict[str, dict[tuple[str, str], int]]) -> list[str]:
    """``Run.job_notes()`` as lines: ``failed (3 jobs): krls: ValueError: ...`` and ``warning (8 jobs): ...``."""
    def jobs(n: int) -> str:
        return f"{n} job{'s' * (n != 1)}"

    lines = [f"failed ({jobs(n)}): {method}: {reason}" for (method, reason), n in notes.get("failed", {}).items()]
    lines += [f"warning ({jobs(n)}): {text}" for (_method, text), n in notes.get("warnings", {}).items()]
    return lines
