"""The C steps of the exportable built-in methods (each method's ``c_model`` hook calls one of these).

Each reproduces its method's prediction arithmetic in the same order where the order matters for
rounding (ARX: the input sum per lag, then the output lags as ``lfilter``'s direct form II transposed
accumulates them); a Gaussian kernel is exp(-g |z - c|^2) summed directly (numpy forms the squared
distances through |z|^2 - 2 z.c + |c|^2), so the two differ by rounding only.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from enginebench.c_model import CModel, c_double


def arx_c(fitted: Any) -> CModel:
    """``arx``: per target y = c + sum_l sum_i b u_i(t-nk-l) + sum_l a_l y(t-l), raw units."""
    k, m = len(fitted.target_names), len(fitted.input_names)
    na, nb, nk = int(fitted.na), int(fitted.nb), int(fitted.nk)
    body = f"""    for (int j = 0; j < NY; j++) {{
        double v = ARX_C[j];
        for (int l = 0; l < {nb}; l++) {{
            double s = 0.0;
            for (int i = 0; i < NU; i++) s += uh[i * LU + {nk} + l] * ARX_B[(j * NU + i) * {nb} + l];
            v += s;
        }}
        double acc = 0.0;
        for (int l = {na} - 1; l >= 0; l--) acc = acc + ARX_A[j * {max(na, 1)} + l] * yh[j * LY + l];
        ys[j] = acc + v;
    }}"""
    return CModel(method="arx", inputs=tuple(fitted.input_names), targets=tuple(fitted.target_names),
                  u_lags=nk + nb, y_lags=na, body=body,
                  constants={"ARX_A": np.asarray(fitted.a, dtype=np.float64).reshape(k, na),
                             "ARX_B": np.asarray(fitted.b, dtype=np.float64).reshape(k, m, nb),
                             "ARX_C": np.asarray(fitted.c, dtype=np.float64).reshape(k)},
                  lower=fitted.envelope.lower, upper=fitted.envelope.upper)


def _boxed(expr: str, lo: float, hi: float) -> str:
    """``expr`` clipped to [lo, hi] as ``np.clip`` does it (a NaN stays NaN, unlike fmin/fmax); unclipped when the
    range is unbounded (``narx``'s kernel box)."""
    if not (np.isfinite(lo) or np.isfinite(hi)):
        return expr
    return f"eb_clip({expr}, {c_double(lo)}, {c_double(hi)})"


EB_CLIP = "static inline double eb_clip(double x, double lo, double hi) { return x < lo ? lo : (x > hi ? hi : x); }"


def narx_c(fitted: Any) -> CModel:
    """``narx``: per target (standardised) kernel sum + (output lags + (input lags + c0)), as ``free_run``, the kernel
    reading its regressors clipped to the fitted kernel box."""
    consts: dict[str, np.ndarray] = {}
    box = fitted.kernel_box()
    parts = []
    na_max = max(md.na for md in fitted.models)
    lu = max(md.nk + md.nb for md in fitted.models)
    for g, md in enumerate(fitted.models):
        d = int(md.centres.shape[1])
        consts[f"NX{g}_A"] = np.asarray(md.a, dtype=np.float64)
        consts[f"NX{g}_B"] = np.asarray(md.b, dtype=np.float64)
        consts[f"NX{g}_C"] = np.asarray(md.centres, dtype=np.float64)
        consts[f"NX{g}_BETA"] = np.asarray(md.beta, dtype=np.float64)
        j = int(md.target)
        z = [_boxed(f"yh[{j} * LY + {md.ka - q - 1}]", box.y_lo[j], box.y_hi[j]) for q in range(md.ka)]
        c = md.b.shape[0]
        z += [_boxed(f"uh[{i} * LU + {md.nk + l}]", box.u_lo[i], box.u_hi[i]) for i in range(c) for l in range(md.kb)]
        zdecl = ", ".join(z) if z else "0.0"
        parts.append(f"""    {{ /* target {j} */
        const double z[{max(len(z), 1)}] = {{{zdecl}}};
        double kern = 0.0;
        for (int i = 0; i < {len(md.beta)}; i++) {{
            double dist = 0.0;
            for (int q = 0; q < {d}; q++) {{ double e = z[q] - NX{g}_C[i * {d} + q]; dist += e * e; }}
            kern += NX{g}_BETA[i] * exp(-{c_double(md.gamma / md.d)} * dist);
        }}
        double hist = 0.0;
        for (int l = 0; l < {md.na}; l++) hist += NX{g}_A[l] * yh[{j} * LY + l];
        double v = 0.0;
        for (int i = 0; i < {c}; i++) for (int l = 0; l < {md.nb}; l++) v += uh[i * LU + {md.nk} + l] * NX{g}_B[i * {md.nb} + l];
        ys[{j}] = kern + (hist + (v + {c_double(md.c0)}));
    }}""")
    return CModel(method="narx", inputs=tuple(fitted.input_names), targets=tuple(fitted.target_names),
                  u_lags=lu, y_lags=na_max, body="\n".join(parts), constants=consts,
                  u_mean=fitted.u_mean, u_std=fitted.u_std, y_mean=fitted.y_mean, y_std=fitted.y_std,
                  lower=fitted.envelope.lower, upper=fitted.envelope.upper, prelude=EB_CLIP + "\n")


def narx_mimo_c(fitted: Any) -> CModel:
    """``narx`` with ``shared_kernel``: one kernel on every output's lags and the inputs, its weights shared by the
    outputs (each its own column of beta), plus each output's linear part on every output's lags, as
    ``mimo_free_run``."""
    md = fitted.mimo
    k, c, d = md.k, md.b.shape[0], int(md.centres.shape[1])
    consts = {"NM_A": np.asarray(md.a, dtype=np.float64), "NM_B": np.asarray(md.b, dtype=np.float64),
              "NM_C0": np.asarray(md.c0, dtype=np.float64), "NM_C": np.asarray(md.centres, dtype=np.float64),
              "NM_BETA": np.asarray(md.beta, dtype=np.float64)}
    box = fitted.kernel_box()
    z = [_boxed(f"yh[{p} * LY + {md.ka - q - 1}]", box.y_lo[p], box.y_hi[p]) for p in range(k) for q in range(md.ka)]
    z += [_boxed(f"uh[{i} * LU + {md.nk + l}]", box.u_lo[i], box.u_hi[i]) for i in range(c) for l in range(md.kb)]
    body = f"""    const double z[{d}] = {{{", ".join(z)}}};
    double kern[{k}];
    for (int o = 0; o < {k}; o++) kern[o] = 0.0;
    for (int i = 0; i < {len(md.beta)}; i++) {{
        double dist = 0.0;
        for (int q = 0; q < {d}; q++) {{ double e = z[q] - NM_C[i * {d} + q]; dist += e * e; }}
        double w = exp(-{c_double(md.gamma / md.d)} * dist);
        for (int o = 0; o < {k}; o++) kern[o] += NM_BETA[i * {k} + o] * w;
    }}
    for (int o = 0; o < {k}; o++) {{
        double hist = 0.0;
        for (int l = 0; l < {md.na}; l++) for (int p = 0; p < {k}; p++) hist += NM_A[(l * {k} + p) * {k} + o] * yh[p * LY + l];
        double v = 0.0;
        for (int i = 0; i < {c}; i++) for (int l = 0; l < {md.nb}; l++) v += uh[i * LU + {md.nk} + l] * NM_B[(i * {md.nb} + l) * {k} + o];
        ys[o] = kern[o] + (hist + (v + NM_C0[o]));
    }}"""
    return CModel(method="narx", inputs=tuple(fitted.input_names), targets=tuple(fitted.target_names),
                  u_lags=md.nk + md.nb, y_lags=md.na, body=body, constants=consts,
                  u_mean=fitted.u_mean, u_std=fitted.u_std, y_mean=fitted.y_mean, y_std=fitted.y_std,
                  lower=fitted.envelope.lower, upper=fitted.envelope.upper, prelude=EB_CLIP + "\n")


def naive_mean_c(fitted: Any) -> CModel:
    """``naive-mean``: the training mean of each target, whatever the inputs (no inputs; the data's targets)."""
    mean = np.asarray(fitted, dtype=np.float64).ravel()
    return CModel(method="naive-mean", inputs=(), targets=(), u_lags=1, y_lags=0,
                  body="    for (int j = 0; j < NY; j++) ys[j] = NAIVE_MEAN[j];", constants={"NAIVE_MEAN": mean},
                  y_mean=np.zeros(len(mean)), y_std=np.ones(len(mean)))


def kernel_sum_c(prefix: str, d: int, n: int, gamma: float) -> str:
    """C statements setting ``ys`` to the Gaussian kernel sum of the scaled features ``x[d]`` over ``n`` centres,
    as ``numerics.kernels.gaussian_apply`` computes it (|x|^2 - 2 x.c + |c|^2 clipped at 0, exp(-gamma D), times
    alpha, plus the outputs' mean): the constants ``{prefix}_X``, ``_XN``, ``_ALPHA``, ``_YMEAN``."""
    return f"""
    double xx = 0.0;
    for (int q = 0; q < {d}; q++) xx += x[q] * x[q];
    for (int j = 0; j < NY; j++) ys[j] = 0.0;
    for (int r = 0; r < {n}; r++) {{
        double dot = 0.0;
        for (int q = 0; q < {d}; q++) dot += x[q] * {prefix}_X[r * {d} + q];
        double dist = dot * -2.0 + xx + {prefix}_XN[r];
        if (!(dist > 0.0)) dist = 0.0;
        double w = exp(dist * -{c_double(gamma)});
        for (int j = 0; j < NY; j++) ys[j] += w * {prefix}_ALPHA[r * NY + j];
    }}
    for (int j = 0; j < NY; j++) ys[j] += {prefix}_YMEAN[j];"""


def nfir_c(fitted: Any, targets: tuple[str, ...] = ()) -> CModel:
    """``nfir``: Gaussian-kernel regression on the inputs at the fitted lags (edge padding), no feedback."""
    k = fitted.krls
    lags = np.asarray(fitted.lags, dtype=np.int64)
    d = len(fitted.inputs) * len(lags)
    mean = np.zeros(d) if getattr(k.scaler, "mean_", None) is None else np.asarray(k.scaler.mean_, dtype=np.float64)
    scale = np.ones(d) if getattr(k.scaler, "scale_", None) is None else np.asarray(k.scaler.scale_, dtype=np.float64)
    alpha = np.asarray(k.alpha, dtype=np.float64)
    n, ny = alpha.shape
    body = f"""    double x[{d}];
    for (int i = 0; i < NU; i++) for (int l = 0; l < {len(lags)}; l++) {{
        int q = i * {len(lags)} + l;
        x[q] = (uh[i * LU + NF_LAGS[l]] - NF_MEAN[q]) / NF_SCALE[q];
    }}
""" + kernel_sum_c("NF", d, n, k.gamma)
    return CModel(method="nfir", inputs=tuple(fitted.inputs), targets=targets, u_lags=int(lags.max()) + 1, y_lags=0,
                  body=body, constants={"NF_LAGS": lags, "NF_MEAN": mean, "NF_SCALE": scale,
                                        "NF_X": np.asarray(k.X_train, dtype=np.float64), "NF_ALPHA": alpha,
                                        "NF_XN": np.einsum("ij,ij->i", k.X_train, k.X_train),
                                        "NF_YMEAN": np.asarray(k.y_mean, dtype=np.float64).reshape(ny)},
                  y_mean=np.zeros(ny), y_std=np.ones(ny))


def _input_lag(name: str, inputs: tuple[str, ...]) -> tuple[int, int] | None:
    """(input index, lag) of a feature column that is an input: the input itself (static mode) or ``u[t]``,
    ``u[t-k]`` (window mode, ``samples.lagged_feature_names``); None for any other column (a past output)."""
    if name in inputs:
        return inputs.index(name), 0
    base, bracket, inner = name.rpartition("[")
    if not bracket or not inner.endswith("]") or base not in inputs:
        return None
    inner = inner[:-1]
    if inner == "t":
        return inputs.index(base), 0
    if inner.startswith("t-") and inner[2:].isdigit() and int(inner[2:]) > 0:
        return inputs.index(base), int(inner[2:])
    return None


def krls_c(fitted: Any, targets: tuple[str, ...] = ()) -> CModel:
    """``krls``: y = sum_r alpha_r exp(-gamma |s(x) - c_r|^2) + y_mean, s(x) = (x - mean) / scale (the training
    scaler), the c_r the scaled training rows (or FALKON's Nystroem centres). The features must be inputs at
    lag 0 (static mode) or at lags the input histories hold; a feature that is a past measured output (window
    mode) has no place in a free-running FMU: MethodError (one line)."""
    from enginebench.errors import MethodError

    names, inputs = tuple(fitted.feature_names), tuple(fitted.input_names)
    if not names:
        raise MethodError("method 'krls' cannot be exported: this stored model does not name its features (stored "
                          "before krls had a C step); run the experiment again with --keep-models")
    where = [_input_lag(n, inputs) for n in names]
    bad = [n for n, w in zip(names, where) if w is None]
    if bad:
        raise MethodError(f"method 'krls' cannot be exported: its feature {bad[0]!r} is not an input but a past "
                          "measured output (window mode), which an FMU does not receive after its init window; "
                          "export a static-mode run of krls")
    used = sorted({i for i, _ in where})  # the inputs read, in the data's order
    lu = max(lag for _, lag in where) + 1
    cols = np.array([used.index(i) * lu + lag for i, lag in where], dtype=np.int64)
    d = len(names)
    mean = np.zeros(d) if getattr(fitted.scaler, "mean_", None) is None else np.asarray(fitted.scaler.mean_, dtype=np.float64)
    scale = np.ones(d) if getattr(fitted.scaler, "scale_", None) is None else np.asarray(fitted.scaler.scale_, dtype=np.float64)
    centres = np.ascontiguousarray(fitted.X_train, dtype=np.float64)
    alpha = np.asarray(fitted.alpha, dtype=np.float64)
    n, ny = alpha.shape
    # the arithmetic of ``gaussian_apply``: |x|^2 - 2 x.c + |c|^2 clipped at 0, exp(-gamma D), times alpha
    body = f"""    double x[{d}];
    for (int q = 0; q < {d}; q++) x[q] = (uh[KR_COL[q]] - KR_MEAN[q]) / KR_SCALE[q];
""" + kernel_sum_c("KR", d, n, fitted.gamma)
    return CModel(method="krls", inputs=tuple(inputs[i] for i in used), targets=targets, u_lags=lu, y_lags=0,
                  body=body, constants={"KR_COL": cols, "KR_MEAN": mean, "KR_SCALE": scale, "KR_X": centres,
                                        "KR_ALPHA": alpha, "KR_XN": np.einsum("ij,ij->i", centres, centres),
                                        "KR_YMEAN": np.asarray(fitted.y_mean, dtype=np.float64).reshape(ny)},
                  y_mean=np.zeros(ny), y_std=np.ones(ny))


PM_FEATURE = "pm:"
"""Prefix of a hybrid's feature column that is the physical model's prediction of a target (``pm:<target>``)."""


def _cannot(method: str, why: str) -> Exception:
    from enginebench.errors import MethodError

    return MethodError(f"method {method!r} cannot be exported: {why}")


def pm_step_c(method: str, pm_name: str, pm_params: Any, dt: float, targets: tuple[str, ...]) -> CModel:
    """The C step of the dataset's physical model ``pm_name`` with ``pm_params`` at ``dt`` (its ``c_model``), or a
    MethodError (one line) where that model has none."""
    from enginebench.physical import get_physical_model

    try:
        pm = get_physical_model(pm_name) if pm_name else None
    except (TypeError, ValueError):  # a model built from its dataset's metadata alone (an FMU's)
        pm = None
    make = getattr(pm, "c_model", None)
    if make is None:
        raise _cannot(method, f"its physical model {pm_name!r} has no C step (the marine-diesel-pm and "
                              "gas-turbine-tat models have one); export a method without it (krls)")
    model = make(pm_params, float(dt), tuple(targets))
    if tuple(model.targets) != tuple(targets) or any(v is not None for v in (model.u_mean, model.u_std,
                                                                             model.y_mean, model.y_std)):
        raise _cannot(method, f"the C step of physical model {pm_name!r} does not give {', '.join(targets)} in raw "
                              "units; please report this")
    return model


def pm_kernel_c(method: str, *, pm_name: str, pm_params: Any, dt: float, targets: tuple[str, ...],
                inputs: tuple[str, ...], features: tuple[str, ...], scaler: Any, centres: np.ndarray,
                alpha: np.ndarray, gamma: float, y_mean: np.ndarray, residual: bool) -> CModel:
    """A KRLS hybrid's step: the physical model's prediction p (its own C step, with its states), the features
    s = ((inputs at their lags, p) - mean) / scale as the training scaler, y = sum_r alpha_r exp(-gamma |s - c_r|^2)
    + y_mean (``kernel_sum_c``, the arithmetic of ``gaussian_apply``), plus p for residual learning. The
    features must be inputs (static mode, or window mode on inputs alone) or ``pm:<target>``; a past measured
    output (window mode with Delta > 0) is refused in one line, as is a physical model without a C step."""
    if not pm_name or not targets or not features:
        raise _cannot(method, "this stored model does not name its physical model and features (stored before the "
                              "hybrids had a C step); run the experiment again with --keep-models")
    where: list[tuple[str, int, int]] = []
    for name in features:
        if name.startswith(PM_FEATURE) and name[len(PM_FEATURE):] in targets:
            where.append(("p", targets.index(name[len(PM_FEATURE):]), 0))
            continue
        at = _input_lag(name, inputs)
        if at is None:
            raise _cannot(method, f"its feature {name!r} is not an input but a past measured output (window mode), "
                                  "which an FMU does not receive after its init window; export a static-mode run "
                                  "(or a window of 0 s)")
        where.append(("u", *at))
    pm = pm_step_c(method, pm_name, pm_params, dt, targets)
    missing = [c for c in pm.inputs if c not in inputs]
    if missing:
        raise _cannot(method, f"its physical model reads {', '.join(missing)}, which are not among the model's "
                              "inputs; please report this")
    used = sorted({inputs.index(c) for c in pm.inputs} | {i for kind, i, _ in where if kind == "u"})
    lu = max([int(pm.u_lags), 1] + [lag + 1 for kind, _, lag in where if kind == "u"])
    pm_cols = np.array([used.index(inputs.index(c)) for c in pm.inputs], dtype=np.int64)
    d = len(features)
    mean = np.zeros(d) if getattr(scaler, "mean_", None) is None else np.asarray(scaler.mean_, dtype=np.float64)
    scale = np.ones(d) if getattr(scaler, "scale_", None) is None else np.asarray(scaler.scale_, dtype=np.float64)
    centres = np.ascontiguousarray(centres, dtype=np.float64)
    alpha = np.asarray(alpha, dtype=np.float64)
    n, ny = alpha.shape
    feats = []
    for q, (kind, i, lag) in enumerate(where):
        src = f"p[{i}]" if kind == "p" else f"uh[{used.index(i)} * LU + {lag}]"
        feats.append(f"    x[{q}] = ({src} - HY_MEAN[{q}]) / HY_SCALE[{q}];")
    # the PM's body in a function of its own: its inputs at HY_PMCOL (every lag), its outputs p, its states
    prelude = pm.prelude + f"""
static void eb_pm(const double *uh, double *ys, const double *xs, double *xn, long n) {{
{pm.body}
}}
"""
    body = f"""    double pu[{len(pm.inputs)} * LU];
    for (int i = 0; i < {len(pm.inputs)}; i++) for (int l = 0; l < LU; l++) pu[i * LU + l] = uh[HY_PMCOL[i] * LU + l];
    double p[NY];
    eb_pm(pu, p, xs, xn, n);
    double x[{d}];
""" + "\n".join(feats) + kernel_sum_c("HY", d, n, gamma)
    if residual:
        body += "\n    for (int j = 0; j < NY; j++) ys[j] = ys[j] + p[j];"
    consts = {"HY_PMCOL": pm_cols, "HY_MEAN": mean, "HY_SCALE": scale, "HY_X": centres, "HY_ALPHA": alpha,
              "HY_XN": np.einsum("ij,ij->i", centres, centres),
              "HY_YMEAN": np.asarray(y_mean, dtype=np.float64).reshape(ny)}
    clash = sorted(set(consts) & set(pm.constants))
    if clash:
        raise _cannot(method, f"its physical model's C step defines {clash[0]} too; please report this")
    return CModel(method=method, inputs=tuple(inputs[i] for i in used), targets=tuple(targets), u_lags=lu, y_lags=0,
                  body=body, constants={**pm.constants, **consts}, y_mean=np.zeros(ny), y_std=np.ones(ny),
                  n_state=int(pm.n_state), prelude=prelude, tolerance=pm.tolerance)


def hybrid_c(method: str, fitted: Any) -> CModel:
    """The C step of a fitted hybrid strategy (``methods/hybrid.py``'s ``HybridFitted``: KRLS with the PM as a
    feature, on its residual, or both; MTL-KRLS's shared or y-task model) or of ``mtl-krls`` (``MTLFitted``)."""
    model = getattr(fitted, "model", fitted)
    strategy = getattr(fitted, "strategy", "shared")
    is_mtl = hasattr(model, "theta")
    return pm_kernel_c(method, pm_name=str(getattr(fitted, "pm_name", "") or getattr(model, "pm_name", "")),
                       pm_params=fitted.pm_params, dt=float(getattr(fitted, "dt", 0.0) or getattr(model, "dt", 0.0)),
                       targets=tuple(getattr(fitted, "target_names", ()) or getattr(model, "target_names", ())),
                       inputs=tuple(model.input_names), features=tuple(model.feature_names), scaler=model.scaler,
                       centres=model.X_train, alpha=model.alpha, gamma=float(model.gamma),
                       y_mean=model.offset if is_mtl else model.y_mean,
                       residual=not is_mtl and strategy in ("residual", "residual-feature"))
