"""What a trained mixture says: local linear systems, the frozen-stability verdict, gate weights, describe."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from enginebench.errors import MethodError
from enginebench.methods.moe.fitted import MoEFitted, build_network, standardise_sched, torch_dtype, unstandardise_sched
from enginebench.methods.moe.simulation import simulate
from enginebench.samples import Samples


def describe(fitted: MoEFitted) -> dict[str, Any]:
    """Expert count, hyperparameters, local linear systems and the frozen-stability verdict."""
    names = fitted.scheduler_names
    net = build_network(fitted, torch.device("cpu"))
    with torch.no_grad():
        gate = net.gate(torch.as_tensor(fitted.probe, dtype=torch_dtype(fitted.options["dtype"]))).numpy()
    # representative points: the median training scheduler point and each expert's home point
    pts = np.vstack([np.median(fitted.probe, axis=0), fitted.probe[np.argmax(gate, axis=0)]])
    labels = ["median"] + [f"expert {i} dominant" for i in range(gate.shape[1])]
    raw = unstandardise_sched(fitted, pts)
    loc = local_coefficients(fitted, raw)
    systems = [
        {
            "label": lab,
            "scheduler": dict(zip(names, map(float, raw[j]))),
            "gate": loc["gate"][j].tolist(),
            "A": loc["A"][j].tolist(),
            "B": loc["B"][j].tolist(),
            "c": loc["c"][j].tolist(),
        }
        for j, lab in enumerate(labels)
    ]
    return {
        "n_experts": int(fitted.params["n_experts"]),
        "hyperparameters": {k: _plain(v) for k, v in fitted.params.items()},
        "state": list(fitted.target_names),
        "inputs": list(fitted.expert_inputs),
        "schedulers": list(names),
        "signs": {
            f"d{t}/dt <- {c}": ("+" if s > 0 else "-")
            for t, row in zip(fitted.target_names, fitted.sign)
            for c, s in zip(fitted.regressor_names, row)
            if s != 0
        },
        "local_systems": systems,
        "frozen_stability": frozen_stability(fitted),
        "warm_start": {k: v for k, v in fitted.init_info.items() if k != "theta"},
        # local systems are in corrected units for the columns named here (option correct)
        "corrected": {c: dict(by) for c, by in (fitted.options.get("correct") or {}).items()},
        "max_time_constant_s": fitted.options.get("max_time_constant"),
        "sim_weight": fitted.options.get("sim_weight", 0.0),
        "final_loss": fitted.loss_history[-1] if fitted.loss_history else None,
    }


def local_coefficients(fitted: MoEFitted, points: np.ndarray) -> dict[str, np.ndarray]:
    """The local linear systems dy/dt = A y + B u + c at scheduler ``points``, in raw units.

    ``points`` is (P, n_sched) in raw units, columns in ``fitted.scheduler_names`` order.
    Returns ``gate`` (P, M) and the gated ``A`` (P, k, k), ``B`` (P, k, n_u), ``c``
    (P, k), plus each expert's ``expert_A`` (P, M, k, k), ``expert_B``, ``expert_c``.
    """
    points = np.atleast_2d(np.asarray(points, dtype=np.float64))
    if points.shape[1] != len(fitted.scheduler_names):
        raise MethodError(
            f"method 'moe': scheduler points have {points.shape[1]} columns; expected {len(fitted.scheduler_names)} "
            f"({', '.join(fitted.scheduler_names)})"
        )
    net = build_network(fitted, torch.device("cpu"))
    v = torch.as_tensor(standardise_sched(fitted, points), dtype=torch_dtype(fitted.options["dtype"]))
    with torch.no_grad():
        G = net.coefficients(v).double().numpy()  # (P, M, k, q)
        gate = net.gate(v).double().numpy()
    k, ne = len(fitted.target_names), len(fitted.expert_inputs)
    ei = [fitted.augmented_names.index(c) for c in fitted.expert_inputs]
    u_mean, u_scale = fitted.u_mean[ei], fitted.u_scale[ei]
    row = (fitted.y_scale * fitted.d_scale)[:, None]  # dy_j/dt = y_scale_j d_scale_j (G [z; u; 1])_j
    A = G[..., :k] * row / fitted.y_scale
    B = G[..., k : k + ne] * row / u_scale
    g1 = G[..., k + ne] if fitted.options["bias"] else np.zeros(G.shape[:-1])
    c = g1 * row[:, 0] - A @ fitted.y_mean - B @ u_mean
    mix = lambda a: np.einsum("pm,pm...->p...", gate, a)  # noqa: E731
    return {"gate": gate, "A": mix(A), "B": mix(B), "c": mix(c), "expert_A": A, "expert_B": B, "expert_c": c}


def frozen_stability(fitted: MoEFitted) -> dict[str, Any]:
    """The turboshaft-moe paper's frozen-stability verdict over the training scheduler points.

    ``state_coefficients_negative``: every expert's own-state coefficient is < 0 at every
    probe point (what the sign constraint promises, checked in floating point: a
    softplus that underflows to 0 fails it). ``max_real_eigenvalue``: of the gated A(v)
    over the probe points. ``stable`` needs both; for one output the first implies the
    second, for several outputs cross-couplings can still destabilise A(v). With the
    state among the schedulers (quasi-LPV) A(v) is the frozen coefficient, not a Jacobian.
    """
    loc = local_coefficients(fitted, unstandardise_sched(fitted, fitted.probe))
    diag = np.diagonal(loc["expert_A"], axis1=-2, axis2=-1)  # (P, M, k)
    eig = np.linalg.eigvals(loc["A"]).real
    return {
        "state_coefficients_negative": bool((diag < 0).all()),
        "max_state_coefficient": float(diag.max()),
        "max_real_eigenvalue": float(eig.max()),
        "stable": bool((diag < 0).all() and eig.max() < 0),
        "n_points": int(len(fitted.probe)),
    }


def gate_weights(fitted: MoEFitted, data: Samples) -> list[np.ndarray]:
    """Gate weights over time, one (N, n_experts) array per segment (rows as in ``predict``).

    With the state among the schedulers the gate is evaluated along the simulated
    trajectory (as in the turboshaft-moe paper's figures), never the measured one.
    """
    _, gates, _ = simulate(fitted, data, record_gate=True)
    return [g[s.rows] for g, s in zip(gates, data.segments)]


def _plain(v: Any) -> Any:
    return v.item() if isinstance(v, np.generic) else v

