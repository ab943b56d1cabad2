"""Where the experts start: the sign-bounded least-squares LTI fit of the derivatives, loaded into every expert.

Fitting scheduled coefficients on derivative targets from a random start leaves the slow
part of the dynamics poorly determined; starting every expert at the best linear model
(within the sign constraints) lets Adam refine it into an LPV mixture.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.optimize import lsq_linear

from enginebench.methods.moe.model import MixtureOfExperts


def _inverse_softplus(mag: np.ndarray, k: float) -> np.ndarray:
    """x with log(1 + e^{kx}) / k = mag (> 0), without overflow for large k mag."""
    km = np.asarray(k * mag, dtype=np.float64)
    return np.where(km > 30.0, mag, np.log(np.expm1(np.minimum(km, 30.0))) / k)


def _bounds(sign_row: np.ndarray, margin_row: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """lsq_linear bounds of one output's coefficients: sign -1 -> <= -margin, +1 -> >= margin, 0 free."""
    lo = np.where(sign_row > 0, margin_row, -np.inf)
    hi = np.where(sign_row < 0, -margin_row, np.inf)
    return lo, hi


def lstsq_coefficients(X: np.ndarray, D: np.ndarray, sign: np.ndarray, margin: np.ndarray | None = None) -> np.ndarray:
    """The linear model D ~ X theta^T (theta (k_out, q)) by least squares within the sign bounds.

    A constrained coefficient is bounded (scipy's ``lsq_linear``) instead of fitted freely and
    clipped: when the data prefer the wrong sign, the others adapt to the coefficient at its
    bound. A tiny ridge (1e-6 of the mean diagonal of X^T X) keeps collinear columns finite.
    """
    margin = np.zeros_like(sign) if margin is None else margin
    q = X.shape[1]
    ridge = np.sqrt(1e-6 * np.trace(X.T @ X) / q)
    Xr = np.vstack([X, ridge * np.eye(q)])
    theta = np.empty((D.shape[1], q))
    for j in range(D.shape[1]):
        lo, hi = _bounds(sign[j], margin[j])
        if np.isinf(lo).all() and np.isinf(hi).all():
            theta[j] = np.linalg.lstsq(Xr, np.r_[D[:, j], np.zeros(q)], rcond=None)[0]
        else:
            theta[j] = lsq_linear(Xr, np.r_[D[:, j], np.zeros(q)], bounds=(lo, hi), method="bvls").x
    return theta


def warm_start(
    net: MixtureOfExperts, theta: np.ndarray, sign: np.ndarray, k: float, margin: np.ndarray | None = None,
    shrink: float = 0.1,
) -> None:
    """Start every expert at the linear model theta (k_out, q; network units).

    Fitting scheduled coefficients on derivative targets from a random start leaves the
    slow part of the dynamics (the pole and static gain that dominate an open-loop
    simulation) poorly determined. Each expert's output bias is set to theta (through the
    inverse of the signed softplus; a constrained coefficient at or inside its bound starts
    1e-2 beyond it, since the softplus never reaches 0) and its scheduled part is scaled by
    ``shrink``, so Adam refines a good LTI model into an LPV mixture instead of searching
    from noise.
    """
    margin = np.zeros_like(sign) if margin is None else margin
    raw = np.array(theta, dtype=np.float64)
    on = sign != 0
    excess = np.maximum(sign[on] * raw[on] - margin[on], 1e-2)  # what the softplus must carry
    raw[on] = _inverse_softplus(excess, k)
    with torch.no_grad():
        net.b2.copy_(torch.as_tensor(raw.reshape(-1), dtype=net.b2.dtype).expand_as(net.b2))
        net.w2.mul_(shrink)

