"""Export a stored run to an MLflow tracking store (optional dependency: ``pip install "enginebench[mlflow]"``).

What a run becomes there (parent and child runs, their params, tags, metrics and keys) is
built by ``mlflow_layout`` (``build_layout``); this module talks to MLflow: it checks the
destination, logs the layout and its artefacts, and replaces an earlier export.

Artefacts on the parent run: config.toml, environment.json, run.json, the long table
(table.csv), the selected hyperparameters per job (selected_hyperparameters.csv) and, on
request, the HTML report under ``report/``.

Exporting a run that the experiment already holds (a parent with the same
``enginebench.run_id``) is refused unless ``replace=True`` (``--replace``): the new export
is logged first, then the earlier parent and its children are deleted (MLflow keeps
deleted runs until ``mlflow gc``). A failed export deletes what it had logged.

MLflow 3 refuses a local file store unless ``MLFLOW_ALLOW_FILE_STORE`` is set; a ``file:``
URI (or a plain folder) asked for explicitly sets it for this process unless the variable
is already set.

Artefacts of a new MLflow experiment go where ``artifact_location`` says: under the folder
(or URI) the user names (``artifacts``, the CLI's ``--artifacts``), else, for an
``sqlite:`` store, next to the database (``mlflow.db`` -> ``mlflow-artifacts/``), never
MLflow's default ``./mlruns`` of the current folder; another database (postgresql, mysql,
mssql) needs ``artifacts``. Servers and file stores keep their own default. An existing
experiment keeps the location it was created with. MLflow's usage telemetry is turned off (``MLFLOW_DISABLE_TELEMETRY``) unless
the variable is set: the toolkit makes no network calls of its own accord.
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
import time
import urllib.error
import urllib.request
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from enginebench.errors import EngineBenchError
from enginebench.results import tables
from enginebench.results.mlflow_layout import ExportError, Layout, build_layout, registry_family
from enginebench.results.run_folder import Run
from enginebench.results.units import run_units

__all__ = [
    "BATCH", "INSTALL_HINT", "PARAM_BATCH", "PROBE_TIMEOUT_S", "ExportResult", "MissingDependency",
    "artifact_location", "check_destination", "export_run", "import_mlflow", "resolve_uri"
]

INSTALL_HINT = 'pip install "enginebench[mlflow]"'
BATCH = 900
"""Entities per log_batch call (MLflow accepts at most 1000 metrics, 100 params)."""
PARAM_BATCH = 100
PROBE_TIMEOUT_S = 10.0
_SQL_SCHEMES = ("sqlite", "postgresql", "mysql", "mssql")


class MissingDependency(EngineBenchError):
    """An optional dependency needed by the command is not installed."""


@dataclass
class ExportResult:
    """Where the run went and how much was logged."""

    tracking_uri: str
    experiment_id: str
    mlflow_run_id: str
    """The parent run."""
    child_run_ids: dict[str, str] = field(default_factory=dict)
    """Method -> its child run."""
    params: dict[str, str] = field(default_factory=dict)
    """The parent's params."""
    n_params: int = 0
    """Params logged over parent and children."""
    n_metric_values: int = 0
    artifacts: list[str] = field(default_factory=list)
    replaced: list[str] = field(default_factory=list)
    """Parent runs of earlier exports that were deleted (``replace=True``)."""


def import_mlflow():
    """The ``mlflow`` module and ``MlflowClient``, or a MissingDependency saying how to install them."""
    os.environ.setdefault("MLFLOW_DISABLE_TELEMETRY", "true")
    try:
        import mlflow
        from mlflow.tracking import MlflowClient
    except ImportError:
        raise MissingDependency("MLflow export needs the mlflow package, which is not installed; "
                                f"{INSTALL_HINT}") from None
    return mlflow, MlflowClient


def resolve_uri(uri: str | Path) -> str:
    """A plain folder becomes a ``file:`` URI; other URIs pass through unchanged; an empty one is refused
    (an unset variable must not make an MLflow store in the current folder)."""
    uri = str(uri)
    if not uri.strip():
        raise ExportError("--mlflow '': an empty tracking URI (an unset variable?); give a server "
                          "(http://HOST:PORT), a local folder or a file: URI")
    if re.match(r"^[A-Za-z][A-Za-z0-9+.-]*:", uri) and not re.match(r"^[A-Za-z]:[\\/]", uri):
        return uri
    return Path(uri).expanduser().resolve().as_uri()


def artifact_location(uri: str, experiment: str, artifacts: str | Path | None = None) -> str | None:
    """Where a new MLflow experiment named ``experiment`` in the store at ``uri`` keeps its artefacts.

    Under ``artifacts`` (a folder or a URI) when given; for ``sqlite:///DB`` next to the
    database (``DB-stem-artifacts/``); None (the store's own default) for servers and file
    stores. Each experiment gets its own subfolder (its name made safe, and a hash of it).
    Another database, or an in-memory sqlite one, without ``artifacts`` is refused: MLflow
    would write into ./mlruns of the current folder.
    """
    scheme = uri.split(":", 1)[0].lower()
    db_file = uri[len("sqlite:///"):].split("?")[0] if uri.lower().startswith("sqlite:///") else ""
    if artifacts is not None and str(artifacts).strip():
        root = resolve_uri(artifacts)
    elif db_file not in ("", ":memory:"):
        db = Path(db_file).expanduser().resolve()  # relative: to the current folder, as MLflow opens it
        root = db.with_name(f"{db.stem}-artifacts").as_uri()
    elif scheme.split("+")[0] in _SQL_SCHEMES:
        raise ExportError(f"MLflow store {uri}: a database store has no folder of its own for artefacts, and MLflow "
                          "would write them into ./mlruns of the current folder; pass --artifacts DIR (or a URI)")
    else:
        return None
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", experiment).strip("._") or "experiment"
    digest = hashlib.sha256(experiment.encode("utf-8")).hexdigest()[:8]
    return f"{root.rstrip('/')}/{safe[:80]}-{digest}"


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return " ".join(text.splitlines()[0].split()) if text else type(exc).__name__


def _probe_server(uri: str) -> None:
    """A server URI that refuses connections is one ExportError now, not minutes of MLflow's retries."""
    try:
        with urllib.request.urlopen(uri.rstrip("/") + "/health", timeout=PROBE_TIMEOUT_S):
            pass
    except urllib.error.HTTPError:
        return  # it answered: reachable (authentication and paths are MLflow's business)
    except (urllib.error.URLError, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", exc)
        raise ExportError(f"cannot reach the MLflow server at {uri} ({_first_line(reason)}); start it (mlflow server) "
                          "or check the --mlflow URI") from None


def _client(uri: str, MlflowClient):
    """An MlflowClient for ``uri``, or one ExportError saying why the URI cannot be used."""
    scheme = uri.split(":", 1)[0].lower()
    if scheme in ("http", "https"):
        _probe_server(uri)
    try:
        return MlflowClient(tracking_uri=uri)
    except Exception as exc:  # noqa: BLE001 - unsupported scheme, missing SQL driver: one line for the user
        if "unsupported uri" in str(exc).lower():
            reason = f"the installed mlflow has no tracking store for the scheme {scheme!r}"
            if scheme.split("+")[0] in _SQL_SCHEMES:
                reason += " (database stores need the full mlflow package with SQLAlchemy: pip install mlflow)"
        else:
            reason = _first_line(exc)[:300]
        raise ExportError(f"MLflow cannot use the tracking URI {uri}: {reason}; give a server (http://HOST:PORT), "
                          "a local folder or a file: URI") from None


def _search_all(client, experiment_id: str, query: str) -> list:
    found, token = [], None
    while True:
        page = client.search_runs([experiment_id], query, max_results=1000, page_token=token)
        found += list(page)
        token = getattr(page, "token", None)
        if not token:
            return found


def _quoted(text: str) -> str:
    return "'" + text.replace("\\", "\\\\").replace("'", "\\'") + "'"


def _log(client, run_id: str, params: dict[str, str], metrics: dict[str, float], now: int) -> int:
    from mlflow.entities import Metric, Param

    items = list(params.items())
    for i in range(0, len(items), PARAM_BATCH):
        client.log_batch(run_id, params=[Param(k, v) for k, v in items[i:i + PARAM_BATCH]])
    values = list(metrics.items())
    for i in range(0, len(values), BATCH):
        client.log_batch(run_id, metrics=[Metric(k, v, now, 0) for k, v in values[i:i + BATCH]])
    return len(values)


def _quote_in_name(exc: BaseException, name: str) -> None:
    """MLflow's stores look experiments up by a filter string that a quote in the name breaks: say so."""
    if "'" in name and "filter string" in str(exc):
        raise ExportError(f"MLflow cannot look up or create an experiment named {name!r}: its stores search names "
                          "with a filter that a quote (') breaks; pass --experiment with a name without one") from None


def _destination(client, uri: str, name: str, run_id: str, replace: bool, *,
                 create: bool, artifacts: str | None = None) -> tuple[str | None, list]:
    """(the experiment's id, the runs of earlier exports of ``run_id`` in it), refused if any unless ``replace``.

    ``create``: create a missing experiment (else its id is None), its artefacts under ``artifacts``
    (None: the store's default).
    """
    found = client.get_experiment_by_name(name)
    if found is not None and found.lifecycle_stage != "active":
        raise ExportError(f"MLflow experiment {name!r} at {uri} is deleted; restore it (mlflow experiments restore "
                          f"--experiment-id {found.experiment_id}) or choose another with --experiment")
    if found is None:
        return (client.create_experiment(name, artifact_location=artifacts) if create else None), []
    earlier = _search_all(client, found.experiment_id, f"tags.`enginebench.run_id` = {_quoted(run_id)}")
    if earlier and not replace:
        from mlflow.utils.mlflow_tags import MLFLOW_PARENT_RUN_ID

        parents = [r.info.run_id for r in earlier if MLFLOW_PARENT_RUN_ID not in r.data.tags]
        raise ExportError(f"run {run_id} is already exported to MLflow experiment {name!r} at {uri} (parent run "
                          f"{', '.join(parents) or earlier[0].info.run_id}); pass --replace to log it again and delete "
                          "that export")
    return found.experiment_id, earlier


def check_destination(run: Run, tracking_uri: str | Path, *, experiment: str | None = None,
                      replace: bool = False, artifacts: str | Path | None = None) -> None:
    """Refuse now what ``export_run`` would refuse about the store, creating nothing.

    A URI MLflow cannot use, an unreachable server, a deleted experiment, or an earlier
    export of ``run`` without ``replace``, a database store without a place for artefacts
    (the CLI asks before it builds a report).
    """
    uri = resolve_uri(tracking_uri)
    if uri.startswith("file:"):
        os.environ.setdefault("MLFLOW_ALLOW_FILE_STORE", "true")
    _, MlflowClient = import_mlflow()
    from mlflow.exceptions import MlflowException

    name = experiment or str(run.config().get("name") or run.info().get("name") or run.id)
    artifact_location(uri, name, artifacts)
    client = _client(uri, MlflowClient)
    try:
        _destination(client, uri, name, run.id, replace, create=False)
    except (MlflowException, OSError) as exc:
        _quote_in_name(exc, name)
        raise ExportError(f"MLflow ({uri}): {_first_line(exc)}") from None


def export_run(
    run: Run,
    tracking_uri: str | Path,
    *,
    experiment: str | None = None,
    interval: str | None = None,
    report_dir: str | Path | None = None,
    replace: bool = False,
    artifacts: str | Path | None = None,
    family_of: Callable[[str], str | None] = registry_family,
) -> ExportResult:
    """Log ``run`` to the MLflow tracking store at ``tracking_uri``: a parent run and a child per method.

    See the module docstring for the layout. ``report_dir``: a folder written by
    ``write_report``, logged under ``report/``. ``replace``: delete an earlier export of
    the same run in the same MLflow experiment (refused without it). ``artifacts``: where a new
    MLflow experiment keeps its artefacts (see ``artifact_location``).
    """
    uri = resolve_uri(tracking_uri)
    if uri.startswith("file:"):
        os.environ.setdefault("MLFLOW_ALLOW_FILE_STORE", "true")
    _, MlflowClient = import_mlflow()
    from mlflow.exceptions import MlflowException
    from mlflow.utils.mlflow_tags import MLFLOW_PARENT_RUN_ID

    layout = build_layout(run, interval=interval, family_of=family_of)
    name = experiment or layout.tags["enginebench.experiment"]
    location = artifact_location(uri, name, artifacts)
    client = _client(uri, MlflowClient)
    created: list[str] = []
    try:
        experiment_id, earlier = _destination(client, uri, name, run.id, replace, create=True, artifacts=location)
        earlier_parents = [r.info.run_id for r in earlier if MLFLOW_PARENT_RUN_ID not in r.data.tags]
        now = int(time.time() * 1000)
        parent = client.create_run(experiment_id, run_name=layout.run_name, tags=layout.tags).info.run_id
        created.append(parent)
        n_metrics = _log(client, parent, layout.params, layout.metrics, now)
        n_params = len(layout.params)
        children: dict[str, str] = {}
        for child in layout.children:
            cid = client.create_run(experiment_id, run_name=child.method,
                                    tags={**child.tags, MLFLOW_PARENT_RUN_ID: parent}).info.run_id
            created.append(cid)
            children[child.method] = cid
            n_metrics += _log(client, cid, child.params, child.metrics, now)
            n_params += len(child.params)
            client.set_terminated(cid, child.status)
        artifacts = _log_artifacts(client, parent, run, layout, report_dir)
        client.set_terminated(parent, layout.status)
    except (MlflowException, OSError, ExportError) as exc:
        _quote_in_name(exc, name)
        for run_id in reversed(created):  # leave no half export behind (best effort: the store may be gone)
            try:
                client.delete_run(run_id)
            except Exception:  # noqa: BLE001
                pass
        if isinstance(exc, ExportError):
            raise
        raise ExportError(f"MLflow ({uri}): {_first_line(exc)}") from None
    try:
        for old in earlier:  # only once the new export is complete
            client.delete_run(old.info.run_id)
    except (MlflowException, OSError) as exc:
        raise ExportError(f"MLflow ({uri}): run {run.id} was exported as parent run {parent}, but deleting the "
                          f"earlier export {', '.join(earlier_parents)} failed ({_first_line(exc)}); delete it in "
                          "MLflow") from None
    return ExportResult(tracking_uri=uri, experiment_id=experiment_id, mlflow_run_id=parent, child_run_ids=children,
                        params=layout.params, n_params=n_params, n_metric_values=n_metrics, artifacts=artifacts,
                        replaced=earlier_parents)


def _log_artifacts(client, run_id: str, run: Run, layout: Layout, report_dir: str | Path | None) -> list[str]:
    """The run's own files, the long table, the selected hyperparameters and the report, on the parent run."""
    artifacts = []
    for fname in ("config.toml", "environment.json", "run.json"):
        if (run.path / fname).is_file():
            client.log_artifact(run_id, str(run.path / fname))
            artifacts.append(fname)
    with tempfile.TemporaryDirectory(prefix="enginebench-mlflow-") as tmp:
        (Path(tmp) / "table.csv").write_text(tables.to_csv(layout.table, units=run_units(run.info())),
                                              encoding="utf-8")
        layout.selected.to_csv(Path(tmp) / "selected_hyperparameters.csv", index=False)
        for fname in ("table.csv", "selected_hyperparameters.csv"):
            client.log_artifact(run_id, str(Path(tmp) / fname))
            artifacts.append(fname)
    if report_dir is not None:
        client.log_artifacts(run_id, str(report_dir), artifact_path="report")
        artifacts.append("report/")
    return artifacts
