"""What a run's jobs said, as lines for people: each failure reason and warning once, with its count;
how often each searched hyperparameter was picked at an edge of its grid; whether parts of the run
were finished by other code than created it.

``run_note_lines(run)`` is the one list every view of a run shows (the end of ``run``,
``runs show``, ``table``, the static and the interactive report); ``note_lines``,
``edge_note_lines``, ``resume_note_lines`` and ``coverage_note_lines`` (evaluated records whose
inputs or outputs leave the training range) are its parts.
"""

from __future__ import annotations

from typing import Any, Iterable, Protocol


class _NotedRun(Protocol):
    def job_notes(self) -> dict[str, dict[tuple[str, str], int]]: ...

    def job_metas(self) -> dict[str, dict[str, Any]]: ...

    def info(self) -> dict[str, Any]: ...

    def environment(self) -> dict[str, Any]: ...


def note_lines(notes: dict[str, dict[tuple[str, str], int]]) -> list[str]:
    """``Run.job_notes()`` as lines: ``failed (3 jobs): krls: ValueError: ...`` and ``warning (8 jobs): ...``."""
    def jobs(n: int) -> str:
        return f"{n} job{'s' * (n != 1)}"

    lines = [f"failed ({jobs(n)}): {method}: {reason}" for (method, reason), n in notes.get("failed", {}).items()]
    lines += [f"warning ({jobs(n)}): {text}" for (_method, text), n in notes.get("warnings", {}).items()]
    return lines


def edge_note_lines(metas: Iterable[dict[str, Any]]) -> list[str]:
    """Run-level grid-edge notes from the jobs' metadata (``Run.job_metas().values()``), one line per
    (method, hyperparameter, edge) picked at least once, e.g.
    ``grid edge: krls: gamma at the upper edge of its grid (10000) in 8 of 8 repetitions: widen gamma_grid``.

    Where selection extended the grid to a hyperparameter's declared hard bound (``bound`` in the record)
    the line says so instead of advising to widen the grid.
    Counts the jobs whose selection record (``search.grid_edges``) places the selected value at an
    edge worth a warning (the method's edge rules) among the jobs that searched that
    hyperparameter; "repetitions" when those jobs share one target, window and split, else "jobs".
    Jobs of runs made before the record was stored count for nothing.
    """
    searched: dict[tuple[str, str], list[tuple[Any, Any, Any]]] = {}
    picks: dict[tuple[str, str, str], list[float]] = {}
    options: dict[tuple[str, str], str] = {}
    bounded: set[tuple[str, str, str]] = set()
    for meta in metas:
        search = meta.get("search")
        edges = search.get("grid_edges") if isinstance(search, dict) else None
        if not isinstance(edges, dict):
            continue
        method = str(meta.get("method", "?"))
        for param, where in edges.items():
            if not isinstance(where, dict):
                continue
            searched.setdefault((method, param), []).append((meta.get("target"), meta.get("window"), meta.get("split")))
            if where.get("option"):
                options[(method, param)] = str(where["option"])
            side = where.get("edge")
            if side in ("lower", "upper") and where.get("warn", True):
                picks.setdefault((method, param, side), []).append(float(where[side]))
                if where.get("bound") is not None:
                    bounded.add((method, param, side))
    lines = []
    for (method, param, side), bounds in sorted(picks.items()):
        coords = searched[(method, param)]
        unit = "repetitions" if len(set(coords)) == 1 else "jobs"
        lo, hi = min(bounds), max(bounds)
        at = f"{lo:g}" if lo == hi else f"{lo:g} to {hi:g}"
        option = options.get((method, param))
        advice = ("the search was extended to its declared hard bound and stops there"
                  if (method, param, side) in bounded else f"widen {option or 'its grid'}")
        lines.append(f"grid edge: {method}: {param} at the {side} edge of its grid ({at}) in {len(bounds)} of "
                     f"{len(coords)} {unit}: {advice}")
    return lines


def resume_note_lines(info: dict[str, Any], environment: dict[str, Any]) -> list[str]:
    """One line per resume (run.json's ``resumes``) whose git commit or package versions differ
    from the creation's (environment.json), e.g. ``resumed with other code: created with git
    91da864, resumed 2026-11-26T16:14:30Z with git 307a801 (numpy 2.3.5 -> 2.4.0): jobs of the two
    parts may differ``. Equal code, or a run never resumed, says nothing."""
    lines = []
    made_git, made_packages = environment.get("git_commit"), environment.get("packages") or {}
    for part in info.get("resumes") or []:
        if not isinstance(part, dict):
            continue
        git = part.get("git_commit")
        packages = part.get("packages") or {}
        changed = [f"{name} {made_packages.get(name)} -> {v}" for name, v in sorted(packages.items())
                   if name in made_packages and made_packages.get(name) != v]
        if git == made_git and not changed:
            continue
        detail = f" ({', '.join(changed)})" if changed else ""
        lines.append(f"resumed with other code: created with git {str(made_git)[:7]}, resumed {part.get('at', '?')} "
                     f"with git {str(git)[:7]}{detail}: jobs of the two parts may differ")
    return lines


def coverage_note_lines(info: dict[str, Any]) -> list[str]:
    """One line per (input or output, part) whose evaluated records leave the training range (run.json's
    ``range_coverage``, ``experiments/coverage.py``), naming the record most outside, e.g. ``inputs beyond the
    training range: Force in 1 of 2 test records (most: Level4, 31 % of its rows outside the training's
    [-5.2, 5.1], reaching 0.42 of that span past it): a model fitted on the training records extrapolates
    there``. Runs made before the record was kept say nothing."""
    coverage = info.get("range_coverage")
    if not isinstance(coverage, dict) or not isinstance(coverage.get("outside"), list):
        return []
    totals = coverage.get("records") or {}
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for entry in coverage["outside"]:
        if isinstance(entry, dict):
            key = (str(entry.get("role", "input")), str(entry.get("column")), str(entry.get("part")))
            groups.setdefault(key, []).append(entry)
    lines = []
    for (role, name, part), entries in sorted(groups.items(), key=lambda kv: kv[0][0] != "input"):
        worst = max(entries, key=lambda e: (float(e.get("fraction", 0.0)), float(e.get("reach") or 0.0)))
        records = {(e.get("split"), e.get("segment")) for e in entries}
        reach = worst.get("reach")
        how_far = (f", reaching {reach:.2g} of that span past it" if isinstance(reach, (int, float))
                   else " (constant in training)")
        lines.append(f"{role}s beyond the training range: {name} in {len(records)} of {totals.get(part, '?')} {part} "
                     f"records (most: {worst.get('segment')}, {100 * float(worst.get('fraction', 0.0)):.0f} % of its "
                     f"rows outside the training's [{float(worst.get('low')):.4g}, {float(worst.get('high')):.4g}]"
                     f"{how_far}): a model fitted on the training records extrapolates there")
    return lines


def _edge_warning(text: str) -> tuple[str, str] | None:
    """(method, hyperparameter) of a job's edge warning ("krls: gamma = 1e+04 selected at the upper edge ..."),
    None for any other warning."""
    method, _, rest = text.partition(": ")
    name, eq, after = rest.partition(" = ")
    if eq and " " not in name and (" edge" in after or "hard bound" in after):
        return method, name
    return None


def run_note_lines(run: _NotedRun, width: int | None = None) -> list[str]:
    """Every note on a stored run: resumes with other code, inputs beyond the training range, failure reasons and
    job warnings with their counts (``note_lines``), then the run-level grid-edge notes (``edge_note_lines``).

    A reason or warning longer than ``width`` characters is cut with "..." (None: whole).
    A job's warning about an edge pick (``experiments.selection.edge_warnings``) is left out where the
    grid-edge note names the same method and hyperparameter: each issue is said once.
    """
    def short(text: str) -> str:
        if width is None:
            return text
        text = " ".join(text.split())
        return text if len(text) <= width else text[: width - 3] + "..."

    notes = run.job_notes()
    edges = edge_note_lines(run.job_metas().values())
    covered = {(m, rest.split(" at the ", 1)[0]) for m, rest in (line.split(": ", 2)[1:3] for line in edges)}
    notes = {**notes, "warnings": {(m, t): n for (m, t), n in notes.get("warnings", {}).items()
                                   if _edge_warning(t) not in covered}}  # each edge pick said once: the edge note
    info = run.info()
    return (resume_note_lines(info, run.environment()) + coverage_note_lines(info) + note_lines({kind: {(m, short(t)): n for (m, t), n in found.items()} for kind, found in notes.items()})
            + edges)
