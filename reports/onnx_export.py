"""``enginebench export --onnx``: a run's stored torch model as ONNX graphs, run back with onnxruntime.

The run must have stored its models (``run --keep-models``). The method's ``onnx_model`` hook hands over
the network's encoder and step (``methods/export/onnx.py``); both are exported with ``torch.onnx.export``,
then onnxruntime runs them over every test segment of the run from the same init window the job used, and
the largest difference to the job's predictions at the evaluated rows is the verdict, relative to the
largest |prediction| of each target: 1e-5 for float32 graphs, 1e-9 for float64 ones (``TOLERANCE``).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from enginebench.errors import MethodError, StoreError
from enginebench.reports.fmu_export import Agreement, ExportResult, _windows
from enginebench.results.model_store import StoredModel, load_model
from enginebench.results.realtime import step_figures

TOLERANCE = {"float32": 1e-5, "float64": 1e-9}
"""Largest accepted difference between the graphs' outputs and the run's predictions, relative to the largest
|prediction| of the target, by the network's floating-point type (the in-tool free run is batched over
segments and fuses the input products over time; the graph steps one sample at a time: same arithmetic,
other rounding order)."""


@dataclass
class OnnxExportResult(ExportResult):
    encoder: Path | None = None
    written: bool = False
    """Whether ``path`` and ``encoder`` hold this export: only when it agreed with the run (``ok``); otherwise
    the graphs were removed and whatever was at those paths before is as it was."""


def export_onnx(model_path: Path, out: Path, *, timing: bool = False, run_id: str = "") -> OnnxExportResult:
    """Write ``out`` (the step) and ``OUT.encoder.onnx`` from the stored model ``model_path``, checked against the
    run's test predictions with onnxruntime first: files already at those paths are replaced only by graphs that
    passed the check (``result.written``)."""
    from enginebench.methods.export.onnx import OnnxRunner, require_onnx, write_onnx

    stored: StoredModel = load_model(model_path)
    data = stored.meta["data"]
    name = stored.meta["method"]
    hook = getattr(stored.method, "onnx_model", None)
    model = hook(stored.fitted) if hook is not None else None
    if model is None:
        raise MethodError(f"method {name!r} cannot be exported to ONNX: it offers no torch graph (ONNX: the "
                          "methods whose `methods show` says 'ONNX')")
    if data["mode"] != "simulation":
        raise MethodError(f"method {name!r}: its ONNX graphs step in time; this model was tested in mode "
                          f"{data['mode']!r} (export models of simulation-mode runs)")
    if not stored.check_data:
        raise StoreError(f"{model_path}: the stored model holds no test predictions to check an export against")
    require_onnx()
    in_cols = [data["input_names"].index(c) for c in model.inputs]
    out_cols = [data["target_names"].index(c) for c in model.targets]
    facts = {"run": run_id, "job": stored.meta.get("job"), "params": stored.meta.get("params"),
             "stored_model_sha256": stored.meta.get("sha256"), "versions": stored.meta.get("versions", {}),
             "dt_s": data["dt"], "init_samples": int(data["init_samples"]),
             "units": {k: v for k, v in data.get("units", {}).items() if k in (*model.inputs, *model.targets)}}
    out = Path(out)
    tolerance = TOLERANCE.get(model.dtype, TOLERANCE["float32"])
    # built in a hidden folder beside ``out`` (same file system, same file names, so the graphs' metadata name
    # their final files) and moved over ``out`` and ``OUT.encoder.onnx`` only once they agree with the run: a
    # failed check (or export) removes the staged graphs and never costs the user files already at those paths
    stage = out.with_name(f".{out.name}.unchecked")
    stage.mkdir(parents=True, exist_ok=True)
    try:
        step_path, enc_path = write_onnx(model, stage / out.name, facts)
        runner = OnnxRunner(step_path, enc_path)
        agreement, times = Agreement(), []
        for seg in stored.check_data:
            U = np.asarray(seg["U"], dtype=np.float64)[:, in_cols]
            window = _windows(seg, len(data["target_names"]))[:, out_cols]
            Y, t = runner.simulate(U, window, timing=timing)
            agreement.add(Y, seg, out_cols)
            times.append(t)
        del runner
        written = bool(agreement.max_rel <= tolerance)
        if written:
            os.replace(enc_path, out.with_name(enc_path.name))
            os.replace(step_path, out)
    finally:
        _remove_stage(stage)
    figures: dict[str, Any] = {}
    if timing:
        figures = {"onnxruntime_step": step_figures(np.concatenate(times), float(data["dt"]), "onnxruntime")}
    return OnnxExportResult(path=out, encoder=out.with_name(enc_path.name), method=name,
                            job=str(stored.meta.get("job", {}).get("key")), steps=agreement.steps,
                            max_abs=agreement.max_abs, max_rel=agreement.max_rel, tolerance=tolerance,
                            timing=figures, written=written)


def _remove_stage(stage: Path) -> None:
    """Remove the staging folder of an export and whatever graphs are still in it (none after a passed check)."""
    if stage.is_dir():
        for left in stage.iterdir():
            left.unlink(missing_ok=True)
        stage.rmdir()


def result_json(result: OnnxExportResult) -> str:
    return json.dumps({"onnx": str(result.path), "encoder": str(result.encoder), "method": result.method,
                       "job": result.job, "steps": result.steps, "max_abs_difference": result.max_abs,
                       "max_relative_difference": result.max_rel, "tolerance": result.tolerance, "ok": result.ok,
                       "written": result.written, "timing": result.timing}, indent=1)
