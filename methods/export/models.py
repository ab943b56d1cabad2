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


def narx_c(fitted: Any) -> CModel:
    """``narx``: per target (standardised) kernel sum + (output lags + (input lags + c0)), as ``free_run``."""
    consts: dict[str, np.ndarray] = {}
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
        z = [f"yh[{j} * LY + {md.ka - q - 1}]" for q in range(md.ka)]
        c = md.b.shape[0]
        z += [f"uh[{i} * LU + {md.nk + l}]" for i in range(c) for l in range(md.kb)]
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
                  lower=fitted.envelope.lower, upper=fitted.envelope.upper)


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
