"""``enginebench runs``: the run catalogue (list with filters, show, tag, untag, rm)."""

from __future__ import annotations

import json
import shutil

import click

from enginebench.cli.options import store_option


@click.group()
def runs() -> None:
    """List, inspect, tag and remove the runs of a store."""


@runs.command("list")
@click.option("--dataset", default=None, help="Only runs on this dataset (its name, or a dataset file's name).")
@click.option("--method", default=None, help="Only runs that used this method (a cascade's stages count).")
@click.option("--status", "statuses", multiple=True, metavar="STATUS",
              help="Only runs with this status (repeatable, any matches): finished, failed (finished with failed "
                   "jobs), running, interrupted, damaged.")
@click.option("--tag", "tags", multiple=True, metavar="KEY[=VALUE]",
              help="Only runs with this tag (repeatable, all must match); KEY alone matches any value.")
@click.option("--since", default=None, help="Only runs created since: an ISO date/time (2025-01-31, 2025-01-31T14:30, "
                                            "local time) or an age (30m, 2h, 3d, 1w).")
@click.option("--format", "fmt", type=click.Choice(["term", "csv", "json"]), default="term", show_default=True)
@click.option("--width", type=click.IntRange(min=20), default=None,
              help="Columns of the term table [default: the terminal's, 80 when not a terminal].")
@store_option
def runs_list(dataset, method, statuses, tags, since, fmt, width, store) -> None:
    """A table of the runs: id, status, jobs done/total, created, wall time, name, dataset, methods, tags.

    The term table fits the width: the least useful columns are trimmed, then dropped
    (never the id). A damaged run is listed with its reason.
    """
    from enginebench.results import catalog
    from enginebench.results.store import RunStore

    filters = catalog.Filters.parse(dataset=dataset, method=method, statuses=statuses, tags=tags, since=since)
    rs = RunStore(store)
    found = catalog.select(catalog.entries(rs), filters)
    if fmt == "json":
        click.echo(json.dumps(catalog.catalog_records(found), indent=2))
    elif fmt == "csv":
        click.echo(catalog.catalog_csv(found), nl=False)
    elif not rs.runs():
        click.echo(f"no runs in {rs.root}")
    elif not found:
        click.echo(f"no run in {rs.root} matches the filters")
    else:
        click.echo(catalog.catalog_text(found, width or shutil.get_terminal_size((80, 24)).columns), nl=False)


@runs.command("show")
@click.argument("run_ref", metavar="RUN", default="latest")
@store_option
def runs_show(run_ref: str, store) -> None:
    """Config, environment, tags, plugin files, failure reasons and warnings, timings, a per-method summary of RUN
    and the hyperparameters its jobs selected (per method and target; where repetitions differ, how many jobs
    picked each value: `enginebench table RUN --picks` lists every job, `--folds` the scores behind each pick).

    RUN is an id, a unique id prefix, 'latest' or a run folder."""
    from enginebench.results.notes import run_note_lines
    from enginebench.results.picks import picks_frame, picks_lines
    from enginebench.results.store import open_run
    from enginebench.results.summary import summarize
    from enginebench.results.term import note_text
    from enginebench.results.units import run_units

    run = open_run(run_ref, store)
    info, cfg, env = run.info(), run.config(), run.environment()
    plugins = run.plugins() or []
    # read first: a damaged job file (or jobs folder) is the only line printed
    metrics = run.metrics() if run.job_files() or run.damage() else None
    notes = run_note_lines(run)
    head = [f"run {run.id}: {info.get('status')} ({len(run.job_files())}/{info.get('n_jobs')} jobs, "
            f"{info.get('failed_jobs', 0)} failed), created {info.get('created')}, config hash "
            f"{info.get('config_hash', '')[:12]}",
            f"experiment: {cfg.get('name')} on {cfg.get('dataset')} {cfg.get('dataset_variant', '')}; targets "
            f"{', '.join(map(str, cfg.get('targets') or []))}; mode {cfg.get('mode')}, windows "
            f"{', '.join(f'{float(w):g} s' for w in cfg.get('windows') or [])}; {cfg.get('repetitions')} repetitions, "
            f"seed {cfg.get('seed')}"]
    if info.get("tags"):
        head.append("tags: " + ", ".join(f"{k}={v}" for k, v in info["tags"].items()))
    head.append(f"environment: python {env.get('python')}, {env.get('cpu')} x{env.get('cpu_count')}, gpu "
                f"{env.get('gpu')}, git {env.get('git_commit')}")
    head.append("packages: " + ", ".join(f"{k} {v}" for k, v in (env.get("packages") or {}).items()))
    head += [f"plugin file: {rec.get('path')} (sha256 {str(rec.get('sha256'))[:12]}; "
             f"methods {', '.join(map(str, rec.get('methods', [])))})" for rec in plugins]
    click.echo(note_text(head, hang="  "), nl=False)
    if notes:
        click.echo("\nnotes (the data, and what the jobs said: distinct failure reasons and warnings, with counts):")
        click.echo(note_text(notes, indent="  "), nl=False)
    if metrics is None:
        click.echo("\nno finished job yet")
        return
    times = _times_table(metrics)
    click.echo("\n" + times if times else "", nl=False)
    click.echo(_realtime_table(metrics), nl=False)
    summary = summarize(metrics, interval=cfg.get("interval", "t"))
    click.echo("\n" + _summary_table(summary, run_units(info), cfg.get("interval", "t")), nl=False)
    click.echo("\nselected hyperparameters (`enginebench table RUN --picks` lists every job):")
    click.echo(note_text(picks_lines(picks_frame(run)), indent="  "), nl=False)


def _realtime_table(metrics) -> str:
    """One model step over the test part per method (simulation runs; results/realtime.py), or nothing."""
    from enginebench.results.realtime import realtime_frame
    from enginebench.results.term import grid

    rt = realtime_frame(metrics)
    if rt.empty:
        return ""
    rows = [[r.method, str(r.jobs), f"{r.median_us:.3g}", f"{r.p99_us:.3g}", f"{r.worst_us:.3g}", f"{r.rt_factor:.3g}"]
            for r in rt.itertuples()]
    return ("\none model step over the test part (measured on this run's machine; median of the jobs, largest p99 "
            "and worst):\n" + grid(["method", "jobs", "median [us]", "p99 [us]", "worst [us]", "dt / worst"], rows,
                                   right=[False] + [True] * 5))


def _times_table(metrics) -> str:
    """Mean seconds per job of each method and timed step (fit, select, predict ...), one row per method."""
    from enginebench.results.term import grid

    times = metrics[metrics["metric"].str.startswith("time_")].groupby(["method", "metric"])["value"].mean().unstack()
    steps = list(times.columns)
    if not steps:
        return ""
    header = ["method", *(f"{c[len('time_'):].removesuffix('_s').replace('_', ' ')} [s]" for c in steps)]
    rows = [[m, *(f"{v:.3g}" if v == v else "" for v in times.loc[m, steps])] for m in times.index]
    return "mean seconds per job:\n" + grid(header, rows, right=[False] + [True] * len(steps))


def _summary_table(summary, units: dict[str, str], interval: str) -> str:
    """The main metrics (mae, rmae) per target, window, split and method: mean and interval, 4 significant digits,
    the metric's unit in its column."""
    from enginebench.results.compare import num
    from enginebench.results.term import grid, note_text

    main = summary[summary["metric"].isin(["mae", "rmae"])]
    keys = {"target": "target", "window": "window [s]", "split": "split"}
    fixed = [k for k in keys if len(main) and main[k].nunique() == 1]  # said once above the table
    shown = [k for k in keys if k not in fixed]
    header = [keys[k] for k in shown] + ["method", "metric [unit]", "mean", "95% interval", "n", "failed"]
    rows = []
    for r in main.itertuples():
        unit = "%" if r.metric == "rmae" else units.get(str(r.target), "")
        rows.append([f"{float(r.window):g}" if k == "window" else str(getattr(r, k)) for k in shown]
                    + [r.method, f"{r.metric} [{unit}]" if unit else r.metric, num(r.mean),
                       f"[{num(r.ci_low)}, {num(r.ci_high)}]", str(int(r.n_repeats)), str(int(r.n_failed))])
    what = "bootstrap percentile" if interval == "bootstrap" else "Student-t"
    where = "; ".join(f"{k} {float(main[k].iloc[0]):g} s" if k == "window" else f"{k} {main[k].iloc[0]}" for k in fixed)
    return (note_text([f"mean and {what} 95% interval over repetitions (n){'; ' + where if where else ''}:"])
            + grid(header, rows, right=[k == "window" for k in shown] + [False, False, True, False, True, True],
                   no_wrap=[False] * len(shown) + [True, True, True, False, True, True]))


def _edited(run, tags: dict[str, str]) -> None:
    click.echo(f"run {run.id}: tags {', '.join(f'{k}={v}' for k, v in tags.items()) or 'none'}")


@runs.command("tag")
@click.argument("run_ref", metavar="RUN")
@click.argument("pairs", metavar="KEY=VALUE...", nargs=-1, required=True)
@store_option
def runs_tag(run_ref: str, pairs, store) -> None:
    """Set tags of RUN (a key it has already gets the new value); prints the run's tags."""
    from enginebench.results.catalog import edit_tags, parse_tags
    from enginebench.results.store import RunStore

    tags = parse_tags(pairs, "runs tag")  # checked before the store is read
    run = RunStore(store).get_own(run_ref, "tagged")
    _edited(run, edit_tags(run, add=tags))


@runs.command("untag")
@click.argument("run_ref", metavar="RUN")
@click.argument("keys", metavar="KEY...", nargs=-1, required=True)
@store_option
def runs_untag(run_ref: str, keys, store) -> None:
    """Remove the tags KEY... from RUN; prints the run's tags."""
    from enginebench.results.catalog import edit_tags
    from enginebench.results.store import RunStore

    run = RunStore(store).get_own(run_ref, "untagged")
    _edited(run, edit_tags(run, remove=keys))


@runs.command("rm")
@click.argument("run_refs", metavar="RUN...", nargs=-1, required=True)
@click.option("--yes", is_flag=True, help="Do not ask for confirmation.")
@store_option
def runs_rm(run_refs, yes: bool, store) -> None:
    """Delete runs from the store."""
    from enginebench.results.store import RunStore

    rs = RunStore(store)
    targets = [rs.get_own(ref) for ref in run_refs]
    if not yes:
        click.confirm(f"delete {len(targets)} run(s): {', '.join(r.id for r in targets)}?", abort=True)
    for r in targets:
        r.lock()  # a run another process is writing is refused, naming that process
        shutil.rmtree(r.path)
        r.unlock()
        click.echo(f"deleted {r.id}")
