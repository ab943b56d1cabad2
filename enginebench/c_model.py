"""A fitted model's step as C: the code behind ``enginebench export --fmu`` and the real-time figures.

A method that can be exported returns a ``CModel`` from its ``c_model`` hook: the signals it reads, how
many past samples of them, their scaling, and a C body that computes one step's outputs from those
histories. ``c_source`` wraps the body into a self-contained step core (no allocation, no library but
libm) that reproduces the toolkit's free run (``methods/freerun.py``):

* inputs are scaled, ``us = (u - u_mean) / u_std``, and kept over ``u_lags`` samples (lag 0 = now); before
  the first sample every lag holds the first sample (edge padding);
* with output feedback (``y_lags > 0``) the first ``init`` steps output the measured outputs given to the
  model (the init window, at least one sample), after them the model's own outputs are fed back, in
  scaled units ``ys = (y - y_mean) / y_std``; ``y = ys y_std + y_mean``;
* a step whose outputs leave the envelope (or are not finite) holds every output at the previous step's
  values from there on and sets ``diverged``, as ``Envelope.clip_run``.

``methods/export/fmu.py`` builds an FMI 2.0 co-simulation FMU around the core; ``methods/export/harness.py``
compiles the core with a timing loop (gcc) for the step figures.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np


@dataclass(frozen=True)
class CModel:
    """One fitted model's step in C (see the module docstring for the conventions)."""

    method: str
    inputs: tuple[str, ...]
    targets: tuple[str, ...]
    """Empty: the data's targets, in order (``check_exportable`` fills them in)."""
    u_lags: int
    """Input samples kept per input, the current one included (>= 1): ``uh[i * LU + l]`` is input i at lag l."""
    y_lags: int
    """Past outputs kept per target (0: no feedback): ``yh[j * LY + l]`` is output j at lag l + 1."""
    body: str
    """C statements setting ``ys[j]`` (scaled outputs) from ``uh`` and ``yh`` (scaled histories)."""
    constants: dict[str, np.ndarray] = field(default_factory=dict)
    """Arrays the body reads, emitted as ``static const double NAME[]`` (int64 arrays as ``long``)."""
    u_mean: np.ndarray | None = None
    u_std: np.ndarray | None = None
    y_mean: np.ndarray | None = None
    y_std: np.ndarray | None = None
    lower: np.ndarray | None = None
    """Envelope (physical units); None: outputs are never held."""
    upper: np.ndarray | None = None
    n_state: int = 0
    """Internal states (a physical model's lags): the body reads ``xs`` (this step's, all zero at step 0: the
    body sets its own start from the first inputs when ``n == 0``) and writes ``xn`` (the next step's)."""
    prelude: str = ""
    """C emitted before the body (its own definitions and helper functions)."""
    tolerance: float | None = None
    """Largest relative difference to the run's predictions an export accepts, where the model's own numerics
    allow no less than the float64 default (an iterative solve: its stopping rule); None: the default, 1e-9."""


def c_double(x: float) -> str:
    """A double as C source that reads back to exactly the same value (17 significant digits)."""
    x = float(x)
    if np.isnan(x):
        return "(0.0/0.0)"
    if np.isinf(x):
        return "(1.0/0.0)" if x > 0 else "(-1.0/0.0)"
    return repr(x)


def c_array(name: str, values: np.ndarray) -> str:
    values = np.asarray(values)
    flat = values.ravel()
    if np.issubdtype(values.dtype, np.integer):
        items = ", ".join(str(int(v)) for v in flat) or "0"
        return f"static const long {name}[{max(flat.size, 1)}] = {{{items}}};\n"
    lines = []
    for a in range(0, flat.size, 4):
        lines.append("    " + ", ".join(c_double(v) for v in flat[a:a + 4]))
    return f"static const double {name}[{max(flat.size, 1)}] = {{\n" + (",\n".join(lines) or "    0.0") + "\n};\n"


def _vector(values: np.ndarray | None, n: int, fill: float) -> np.ndarray:
    return np.full(n, fill) if values is None else np.asarray(values, dtype=np.float64).reshape(n)


CORE = r"""
typedef struct {
    double uh[NU * LU + 1];
    double yh[NY * LY + 1];
    double ys[NY];
    double y[NY];
    double held[NY];
    double xs[NX + 1];
    double xn[NX + 1];
    long n;
    long init;
    int diverged;
    int fresh;
} eb_model;

static void eb_body(const double *uh, const double *yh, double *ys, const double *xs, double *xn, long n) {
%(body)s
}

void eb_reset(eb_model *m, long init) {
    memset(m, 0, sizeof(*m));
    m->init = init < 1 ? 1 : init;
}

void eb_set_inputs(eb_model *m, const double *u) {
    for (int i = 0; i < NU; i++) {
        double s = (u[i] - U_MEAN[i]) / U_STD[i];
        if (m->n == 0) { for (int l = 0; l < LU; l++) m->uh[i * LU + l] = s; }
        else m->uh[i * LU] = s;
    }
    m->fresh = 0;
}

/* The outputs of the current step (ymeas: the measured outputs, read inside the init window only). */
const double *eb_outputs(eb_model *m, const double *ymeas) {
    if (m->fresh) return m->y;
    if (FEEDBACK && m->n < m->init) {
        for (int j = 0; j < NY; j++) { m->y[j] = ymeas[j]; m->ys[j] = (ymeas[j] - Y_MEAN[j]) / Y_STD[j]; }
        if (m->n == 0) for (int j = 0; j < NY; j++) for (int l = 0; l < LY; l++) m->yh[j * LY + l] = m->ys[j];
    } else {
        eb_body(m->uh, m->yh, m->ys, m->xs, m->xn, m->n);
        int bad = 0;
        for (int j = 0; j < NY; j++) {
            m->y[j] = m->ys[j] * Y_STD[j] + Y_MEAN[j];
            if (CLIP && !(m->y[j] >= ENV_LO[j] && m->y[j] <= ENV_HI[j])) bad = 1;
        }
        if (CLIP && (bad || m->diverged)) {
            m->diverged = 1;
            for (int j = 0; j < NY; j++) m->y[j] = m->held[j];
        }
    }
    m->fresh = 1;
    return m->y;
}

/* Ends the current step: its outputs join the history, the inputs are held for the next step. */
void eb_commit(eb_model *m, const double *ymeas) {
    eb_outputs(m, ymeas);
    if (!m->diverged) for (int j = 0; j < NY; j++) m->held[j] = m->y[j];
    for (int i = 0; i < NX; i++) m->xs[i] = m->xn[i];
    for (int j = 0; j < NY; j++) {
        for (int l = LY - 1; l > 0; l--) m->yh[j * LY + l] = m->yh[j * LY + l - 1];
        if (LY > 0) m->yh[j * LY] = m->ys[j];
    }
    for (int i = 0; i < NU; i++) for (int l = LU - 1; l > 0; l--) m->uh[i * LU + l] = m->uh[i * LU + l - 1];
    m->n++;
    m->fresh = 0;
}
"""


def c_source(model: CModel) -> str:
    """The step core of ``model`` as one C file (the definitions, the constants, ``eb_model`` and its functions)."""
    nu, ny = len(model.inputs), len(model.targets)
    clip = model.lower is not None and model.upper is not None
    head = ["/* generated by enginebench: the step of a fitted "
            f"{model.method} model ({', '.join(model.inputs)} -> {', '.join(model.targets)}) */",
            "#define _POSIX_C_SOURCE 200112L", "#include <math.h>", "#include <string.h>",
            f"#define NU {nu}", f"#define NY {ny}", f"#define LU {max(int(model.u_lags), 1)}",
            f"#define LY {int(model.y_lags)}", f"#define NX {int(model.n_state)}",
            f"#define FEEDBACK {int(model.y_lags > 0)}", f"#define CLIP {int(clip)}",
            ""]
    consts = [c_array("U_MEAN", _vector(model.u_mean, nu, 0.0)), c_array("U_STD", _vector(model.u_std, nu, 1.0)),
              c_array("Y_MEAN", _vector(model.y_mean, ny, 0.0)), c_array("Y_STD", _vector(model.y_std, ny, 1.0)),
              c_array("ENV_LO", _vector(model.lower, ny, -np.inf)), c_array("ENV_HI", _vector(model.upper, ny, np.inf))]
    consts += [c_array(name, values) for name, values in model.constants.items()]
    return "\n".join(head) + "".join(consts) + model.prelude + CORE % {"body": model.body}


def check_exportable(method: object, fitted: object, targets: Sequence[str]) -> CModel:
    """The method's ``CModel`` of ``fitted`` (a model naming no targets gets ``targets``, the data's), or a
    MethodError (one line) saying it cannot be exported."""
    from enginebench.errors import MethodError

    model = method.c_model(fitted)  # type: ignore[attr-defined]
    if model is None:
        raise MethodError(f"method {getattr(method, 'name', '?')!r} cannot be exported: it offers no C step "
                          "(exportable: the methods whose `methods show` says 'export: FMU')")
    return model if model.targets else replace(model, targets=tuple(targets))


def exportable(method_cls: type) -> bool:
    """Whether a method class offers a C step (overrides ``Method.c_model``)."""
    from enginebench.method import Method

    return getattr(method_cls, "c_model", Method.c_model) is not Method.c_model


def select_columns(names: Sequence[str], wanted: Sequence[str]) -> list[int]:
    return [list(names).index(w) for w in wanted]
