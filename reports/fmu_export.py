"""``enginebench export``: a run's stored model as an FMU, simulated back with fmpy against the run's predictions.

The run must have stored its models (``run --keep-models``): the stored model holds the fitted state and
the test part with the job's predictions of it (``results/model_store.py``). The FMU is built from the
method's C step (``Method.c_model``), then driven by fmpy over every test segment, from the same init
window the job used; the largest difference to the job's predictions at the evaluated rows is the
verdict, relative to the largest |prediction| of each target (``TOLERANCE``: 1e-9, float64). A static- or
window-mode model is exported where its C step reads inputs only (no output feedback; a physical model's
states, as in the KRLS hybrids, start with each segment as the job's simulation of it did): the FMU then steps
over each test segment's inputs and is compared on the rows the job predicted.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from enginebench.errors import MethodError, StoreError
from enginebench.c_model import check_exportable
from enginebench.methods.export.fmu import build_fmu, simulate_fmu
from enginebench.methods.export.harness import CStep
from enginebench.results.model_store import MODELS_DIR, StoredModel, load_model, read_model_file
from enginebench.results.realtime import step_figures

TOLERANCE = 1e-9
"""Largest accepted difference between the FMU's outputs and the run's predictions, relative to the largest
|prediction| of the target (float64 arithmetic in both; only the order of a few sums differs)."""


@dataclass
class ExportResult:
    path: Path
    method: str
    job: str
    steps: int
    max_abs: float
    max_rel: float
    tolerance: float
    timing: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return bool(self.max_rel <= self.tolerance)


def find_model(run_path: Path, run_id: str, method: str, target: str | None, repetition: int | None,
               window: float | None = None) -> Path:
    """The stored model of ``method`` (and ``target``, ``window``, ``repetition``: the lowest one when not given) in
    a run; several targets or windows without a choice are refused (the user names one)."""
    folder = Path(run_path) / MODELS_DIR
    found = []
    for path in sorted(folder.glob("*.npz")) if folder.is_dir() else []:
        try:
            job = read_model_file(path)[0].get("job", {})
        except StoreError:
            continue
        found.append((path, job))
    if not found:
        raise StoreError(f"run {run_id} stored no models; run the experiment again with `enginebench run EXPERIMENT "
                         "--keep-models` (or [store] models = true) to export one")
    mine = [(p, j) for p, j in found if j.get("method") == method]
    if not mine:
        methods = sorted({str(j.get("method")) for _, j in found})
        raise StoreError(f"run {run_id} stored no model of method {method!r}; it stored {', '.join(methods)}")
    if target is not None:
        mine = [(p, j) for p, j in mine if j.get("target") == target or
                (j.get("target") == "(all targets)" and target in read_model_file(p)[0]["data"]["target_names"])]
        if not mine:
            raise StoreError(f"run {run_id}: method {method!r} stored no model of target {target!r}")
    targets = sorted({str(j.get("target")) for _, j in mine})
    if len(targets) > 1:
        raise StoreError(f"run {run_id}: method {method!r} stored models of several targets ({', '.join(targets)}); "
                         "choose one with --target")
    windows = sorted({float(j.get("window", 0.0)) for _, j in mine})
    if window is not None:
        mine = [(p, j) for p, j in mine if float(j.get("window", 0.0)) == float(window)]
        if not mine:
            raise StoreError(f"run {run_id}: method {method!r} stored no model of window {window:g} s; it stored "
                             f"{', '.join(f'{w:g} s' for w in windows)}")
    elif len(windows) > 1:
        raise StoreError(f"run {run_id}: method {method!r} stored models of several windows "
                         f"({', '.join(f'{w:g} s' for w in windows)}); choose one with --window")
    if repetition is not None:
        mine = [(p, j) for p, j in mine if j.get("repetition") == repetition]
        if not mine:
            raise StoreError(f"run {run_id}: method {method!r} stored no model of repetition {repetition}")
    return sorted(mine, key=lambda pj: (pj[1].get("repetition", 0), str(pj[1].get("split")), str(pj[0])))[0][0]


@dataclass
class Agreement:
    """How far an exported model's outputs lie from the run's predictions, segment by segment: the largest absolute
    difference, the largest relative to each output's largest magnitude, and the rows compared."""

    max_abs: float = 0.0
    max_rel: float = 0.0
    steps: int = 0

    def add(self, Y: np.ndarray, seg: dict[str, Any], out_cols: list[int]) -> None:
        """Compare the exported outputs ``Y`` (every row of the segment) on the rows the run scored."""
        rows = np.asarray(seg["rows"], dtype=np.int64)
        pred = np.asarray(seg["prediction"], dtype=np.float64)[:, out_cols]
        diff = np.abs(Y[rows] - pred)
        scale = np.maximum(np.abs(pred).max(axis=0, initial=0.0), np.finfo(float).tiny)
        worst = float(diff.max(initial=0.0))
        rel = float((diff.max(axis=0, initial=0.0) / scale).max(initial=0.0))
        self.max_abs = max(self.max_abs, worst if np.isfinite(worst) else float("inf"))  # NaN out: never agreement
        self.max_rel = max(self.max_rel, rel if np.isfinite(rel) else float("inf"))
        self.steps += len(rows)


def _windows(seg: dict[str, Any], n_targets: int) -> np.ndarray:
    """The measured outputs that start a segment: its init window, else its first output (simulation mode); a
    static or window-mode segment has neither, and a C step without feedback reads none (zeros)."""
    y_init = seg.get("y_init")
    if y_init is not None and len(y_init):
        return y_init
    return np.zeros((1, n_targets)) if seg.get("y0") is None else np.reshape(seg["y0"], (1, -1))


def export_fmu(model_path: Path, out: Path, *, timing: bool = False, tolerance: float = TOLERANCE,
               run_id: str = "") -> ExportResult:
    """Build ``out`` from the stored model ``model_path`` and check it against the run's test predictions."""
    stored: StoredModel = load_model(model_path)
    data = stored.meta["data"]
    model = check_exportable(stored.method, stored.fitted, tuple(data["target_names"]))
    if data["mode"] != "simulation" and model.y_lags:  # states (a physical model's lags) run from each segment's
        # start, as the job simulated the physical model over the whole segment before taking its rows
        raise MethodError(f"method {stored.method.name!r}: its C step runs freely on its own past outputs; "
                          f"this model was tested in mode {data['mode']!r} (export models of simulation-mode runs)")
    tolerance = max(tolerance, model.tolerance or 0.0)  # a model whose solver stops earlier states its own
    if not stored.check_data:
        raise StoreError(f"{model_path}: the stored model holds no test predictions to check an export against")
    in_cols = [data["input_names"].index(c) for c in model.inputs]
    out_cols = [data["target_names"].index(c) for c in model.targets]
    first = stored.check_data[0]
    stop = float(len(first["U"]) - 1) * float(data["dt"])
    resources = {"enginebench": stored.meta.get("versions", {}), "job": stored.meta.get("job"), "run": run_id,
                 "method": stored.meta["method"], "params": stored.meta.get("params"),
                 "stored_model_sha256": stored.meta.get("sha256"), "dt_s": data["dt"],
                 "init_samples": int(data["init_samples"])}
    units = {k: v for k, v in data.get("units", {}).items() if k in (*model.inputs, *model.targets)}
    init = max(int(data["init_samples"]), 1)
    about = (f"{stored.meta['method']} model of {', '.join(model.targets)} from {', '.join(model.inputs) or 'no inputs'}"
             f" (enginebench run {run_id or '?'}, job {stored.meta.get('job', {}).get('key', '?')}); fixed step "
             f"{data['dt']} s")
    # built beside ``out`` and moved over it only once it agrees with the run: a failed check never costs the user
    # an FMU already at ``out``
    path = build_fmu(model, out.with_name(f".{out.name}.unchecked"), dt=float(data["dt"]), init=init, stop=stop, about=about, resources=resources,
                     units=units)
    agreement = Agreement()
    fmu_times, c_times = [], []
    step = CStep(model) if timing else None
    try:
        for seg in stored.check_data:
            U = np.asarray(seg["U"], dtype=np.float64)[:, in_cols]
            window = _windows(seg, len(data["target_names"]))[:, out_cols]
            Y, t = simulate_fmu(path, U, window, len(window), float(data["dt"]), timing=timing)
            agreement.add(Y, seg, out_cols)
            if timing:
                fmu_times.append(t)
                c_times.append(step.run(U, window, len(window), timing=True)[1])  # type: ignore[union-attr]
    finally:
        if step is not None:
            step.close()
    figures: dict[str, Any] = {}
    if timing:
        figures = {"c_step": step_figures(np.concatenate(c_times), float(data["dt"]), "c-step"),
                   "fmu_via_fmpy": step_figures(np.concatenate(fmu_times), float(data["dt"]), "fmpy")}
    if agreement.max_rel <= tolerance:
        path = path.replace(out)
    return ExportResult(path=path, method=stored.meta["method"], job=str(stored.meta.get("job", {}).get("key")),
                        steps=agreement.steps, max_abs=agreement.max_abs, max_rel=agreement.max_rel,
                        tolerance=tolerance, timing=figures)


def result_json(result: ExportResult) -> str:
    return json.dumps({"fmu": str(result.path), "method": result.method, "job": result.job, "steps": result.steps,
                       "max_abs_difference": result.max_abs, "max_relative_difference": result.max_rel,
                       "tolerance": result.tolerance, "ok": result.ok, "timing": result.timing}, indent=1)
