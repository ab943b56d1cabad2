"""What `run` and `learning-curve` do when they are stopped: SIGTERM as SystemExit, and the command that resumes."""

from __future__ import annotations

from typing import TYPE_CHECKING

import click

if TYPE_CHECKING:
    from enginebench.results.run_folder import Run
    from enginebench.results.store import RunStore


def stop_on_sigterm() -> None:
    """Turn SIGTERM (from a scheduler or `timeout`) into SystemExit, so that the run is recorded as interrupted."""
    import signal

    def stop(signum: int, frame: object) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, stop)


def echo_resume_hint(store: RunStore, known: set[str], resume: Run | None = None) -> None:
    """After an interruption: how many jobs of the run (``resume``, else the one not in ``known``) are stored and
    the command that finishes it (on stderr; nothing when no run was created yet)."""
    stopped = resume or next((r for r in reversed(store.runs()) if r.id not in known), None)
    if stopped is None:
        return
    info = stopped.info()
    click.echo(f"interrupted: {info.get('finished_jobs', '?')} of {info.get('n_jobs', '?')} jobs of run "
               f"{stopped.id} are stored; finish it with `enginebench run --resume {stopped.id}`", err=True)
