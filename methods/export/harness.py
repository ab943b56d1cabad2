"""Compile a ``CModel``'s step core with gcc and run it over a record: its outputs and the time of each step.

``run_c(model, U, y_meas, init)`` returns the outputs the C step computes for every sample (what the FMU
outputs) and, with ``timing=True``, the seconds each step took (``clock_gettime(CLOCK_MONOTONIC)``
around set-inputs, outputs and commit; the clock's own cost, some 20-40 ns, is included). The figures
(``results/realtime.step_figures``) are the median, 99th percentile and worst step and the real-time factor
dt / worst. ``c_step_times`` is the ``Method.step_times`` hook of the methods with a C step.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from enginebench.errors import MethodError
from enginebench.c_model import CModel, c_source

CFLAGS = ("-O2", "-std=c99", "-fPIC", "-ffp-contract=off")
"""No fast-math and no fused multiply-add: the C step rounds like the toolkit's numpy arithmetic."""

RUNNER = r"""
#include <time.h>
int eb_run(long n, long init, const double *U, const double *Ym, double *Y, double *times) {
    eb_model m;
    struct timespec a, b;
    eb_reset(&m, init);
    for (long t = 0; t < n; t++) {
        if (times) clock_gettime(CLOCK_MONOTONIC, &a);
        eb_set_inputs(&m, U + t * NU);
        const double *y = eb_outputs(&m, Ym + t * NY);
        for (int j = 0; j < NY; j++) Y[t * NY + j] = y[j];
        eb_commit(&m, Ym + t * NY);
        if (times) {
            clock_gettime(CLOCK_MONOTONIC, &b);
            times[t] = (double)(b.tv_sec - a.tv_sec) + 1e-9 * (double)(b.tv_nsec - a.tv_nsec);
        }
    }
    return m.diverged;
}
"""


def compiler() -> str | None:
    """The C compiler used (``$CC`` or gcc), or None when there is none."""
    return shutil.which(os.environ.get("CC", "gcc"))


def compile_shared(source: str, out: Path, what: str) -> Path:
    """``source`` compiled into the shared library ``out``; MethodError (one line) without a compiler or on errors."""
    cc = compiler()
    if cc is None:
        raise MethodError(f"{what}: no C compiler found (gcc or $CC); install gcc to export or time a model")
    src = out.with_suffix(".c")
    src.write_text(source)
    proc = subprocess.run([cc, *CFLAGS, "-shared", "-o", str(out), str(src), "-lm"], capture_output=True, text=True)
    if proc.returncode != 0:
        lines = proc.stderr.strip().splitlines() or ["?"]
        first = next((ln for ln in lines if "error" in ln), lines[0])
        raise MethodError(f"{what}: the generated C code did not compile ({first}); please report this")
    return out


class CStep:
    """A ``CModel``'s step core compiled once (gcc) and loaded; ``run`` simulates a record with it.
    Use as a context manager (the build folder is removed on exit)."""

    def __init__(self, model: CModel) -> None:
        self.model = model
        source = c_source(model) + RUNNER
        self.dir = tempfile.mkdtemp(prefix="enginebench-c-")
        try:
            name = "eb_" + hashlib.sha256(source.encode()).hexdigest()[:12]
            path = compile_shared(source, Path(self.dir) / f"{name}.so", f"method {model.method!r}")
        except BaseException:
            self.close()
            raise
        self.lib = ctypes.CDLL(str(path))
        p = ctypes.POINTER(ctypes.c_double)
        self.lib.eb_run.argtypes = [ctypes.c_long, ctypes.c_long, p, p, p, p]
        self.lib.eb_run.restype = ctypes.c_int

    def __enter__(self) -> "CStep":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)

    def run(self, U: np.ndarray, y_meas: np.ndarray, init: int, timing: bool = False
            ) -> tuple[np.ndarray, np.ndarray | None, bool]:
        """(outputs (n, targets), step times (n,) or None, diverged) over inputs ``U`` (n, inputs);
        ``y_meas`` (at least ``init`` rows, targets) are the measured outputs of the init window."""
        model = self.model
        n, ny = len(U), len(model.targets)
        U = np.ascontiguousarray(U, dtype=np.float64).reshape(n, len(model.inputs))
        Ym = np.zeros((n, ny))
        w = np.asarray(y_meas, dtype=np.float64).reshape(-1, ny)[:n]
        Ym[:len(w)] = w
        Y = np.empty((n, ny))
        times = np.empty(n) if timing else None
        ptr = ctypes.POINTER(ctypes.c_double)
        diverged = self.lib.eb_run(n, int(init), U.ctypes.data_as(ptr), Ym.ctypes.data_as(ptr),
                                   Y.ctypes.data_as(ptr), times.ctypes.data_as(ptr) if times is not None else None)
        return Y, times, bool(diverged)


def run_c(model: CModel, U: np.ndarray, y_meas: np.ndarray, init: int, timing: bool = False
          ) -> tuple[np.ndarray, np.ndarray | None, bool]:
    """``CStep(model).run(...)`` for one record (compiled for this call alone)."""
    with CStep(model) as step:
        return step.run(U, y_meas, init, timing)


def c_step_times(model: CModel | None, data: Any) -> tuple[str, np.ndarray] | None:
    """``Method.step_times`` of a method with a C step: ``("c-step", seconds of each step)`` of ``model`` (its
    ``c_model``) compiled once and run over every segment of ``data`` (``Samples``: the inputs, and the measured
    outputs of each segment's init window, its first sample without one); None without a model. MethodError (one
    line) without a C compiler or when the generated code does not compile."""
    if model is None:
        return None
    if not model.targets:
        model = replace(model, targets=tuple(data.target_names))
    cols = [list(data.input_names).index(c) for c in model.inputs]
    times = []
    with CStep(model) as step:
        for s in data.segments:
            window = s.y_init if s.y_init is not None and len(s.y_init) else np.reshape(s.y0, (1, -1))
            times.append(step.run(np.asarray(s.U, dtype=np.float64)[:, cols], window, len(window), True)[1])
    return "c-step", (np.concatenate(times) if times else np.empty(0))
