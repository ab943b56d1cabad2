"""Open-loop simulation of a trained mixture: every segment at once from its y0, padded, fixed step.

LPV models (schedulers free of the state) take the affine path: dz/dt = A(t) z + w(t), so
one RK4 or Euler step is z' = Phi z + gamma with Phi, gamma computed for whole chunks of
steps at once. State-scheduled (quasi-LPV) models are integrated step by step with the
shared fixed-step integrator (``numerics.integrate``). Either way a trajectory that goes
non-finite or leaves ``envelope`` times the training range of y is stopped, held and
flagged; no measured output after y0 is read.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from enginebench.errors import MethodError
from enginebench.methods.moe.fitted import MoEFitted, build_network, torch_dtype
from enginebench.methods.moe.model import MixtureOfExperts
from enginebench.methods.moe.preprocess import augment, correction_factors
from enginebench.methods.numerics.device import cpu_threads, resolve_device
from enginebench.methods.numerics.integrate import hold_after_exit, integrate
from enginebench.samples import Samples


def simulate(
    fitted: MoEFitted, data: Samples, record_gate: bool = False, stepwise: bool | None = None
) -> tuple[list[np.ndarray], list[np.ndarray] | None, np.ndarray]:
    """Open-loop simulation of every segment of ``data`` from its y0, batched over segments.

    Returns the trajectories (one (N_s, k) array per segment over all its raw rows), the
    gate weights at every sample (when ``record_gate``), and the per-segment diverged flags.
    ``stepwise`` forces (True) or forbids (False) evaluating the network at every
    integrator stage; by default only state-scheduled models need it, and LPV models use
    the equivalent affine step computed for whole chunks at once.
    """
    device = resolve_device(fitted.options["device"], "method 'moe'")
    with cpu_threads(fitted.options["cpu_threads"], device), torch.no_grad():
        return _simulate(fitted, data, record_gate, stepwise)


def _simulate(
    fitted: MoEFitted, data: Samples, record_gate: bool, stepwise: bool | None = None
) -> tuple[list[np.ndarray], list[np.ndarray] | None, np.ndarray]:
    o = fitted.options
    segs = data.segments
    if data.mode != "simulation":
        raise MethodError(f"method 'moe' simulates open loop: give samples in mode 'simulation', not {data.mode!r}")
    if tuple(data.target_names) != fitted.target_names:
        raise MethodError(f"method 'moe': fitted for targets {fitted.target_names}, asked for {tuple(data.target_names)}")
    missing = [c for c in fitted.input_names if c not in data.input_names]
    if missing:
        raise MethodError(f"method 'moe': the data lack input column(s) {', '.join(missing)} that the model was fitted on")
    if not segs:
        return [], ([] if record_gate else None), np.zeros(0, dtype=bool)
    col = [data.input_names.index(c) for c in fitted.input_names]
    device, dtype = resolve_device(o["device"], "method 'moe'"), torch_dtype(o["dtype"])
    lens = np.array([len(s.U) for s in segs])
    S, L, k = len(segs), int(lens.max()), len(fitted.target_names)
    U = np.empty((S, L, len(fitted.augmented_names)))
    H = np.zeros((S, L - 1))
    z0 = np.empty((S, k))
    f_out = []  # per segment: the correction factors of the targets (raw = corrected x factor)
    for j, s in enumerate(segs):
        if s.y0 is None:
            raise MethodError(f"method 'moe': segment {s.id!r} has no initial output y0 (samples must be in mode 'simulation')")
        u = s.U[:, col]
        if not (np.isfinite(u).all() and np.isfinite(s.y0).all()):
            raise MethodError(f"method 'moe': segment {s.id!r} holds NaN or inf in its inputs or y0; clean or drop it")
        fu, fy = correction_factors(o.get("correct"), fitted.input_names, fitted.target_names, u)
        u = u / fu
        f_out.append(fy)
        u = augment(u, s.t, fitted.derived, fitted.input_names, o["derivative_window"])
        U[j, : len(u)], U[j, len(u) :] = u, u[-1]
        h = np.diff(s.t)
        if (h <= 0).any():
            raise MethodError(f"method 'moe': segment {s.id!r}: time does not increase at row {int(np.argmax(h <= 0)) + 1}")
        H[j, : len(h)] = h  # padding steps have h = 0: the state stays put
        z0[j] = (s.y0 / fy[0] - fitted.y_mean) / fitted.y_scale
    as_t = lambda a: torch.as_tensor(a, dtype=dtype, device=device)  # noqa: E731
    span = fitted.y_max - fitted.y_min
    sim = _Sim(
        options=o,
        n_experts=int(fitted.params["n_experts"]),
        net=build_network(fitted, device),
        U=as_t((U - fitted.u_mean) / fitted.u_scale),
        H=as_t(H),
        lo=as_t((fitted.y_min - o["envelope"] * span - fitted.y_mean) / fitted.y_scale),
        hi=as_t((fitted.y_max + o["envelope"] * span - fitted.y_mean) / fitted.y_scale),
        d_scale=as_t(fitted.d_scale),
        si=[fitted.input_names.index(c) for c in fitted.scheduler_inputs],
        ei=[fitted.augmented_names.index(c) for c in fitted.expert_inputs],
        record_gate=record_gate,
        lengths=lens,
    )
    if stepwise is None:
        stepwise = bool(o["scheduler_state"])
    if not stepwise and o["scheduler_state"]:
        raise MethodError("method 'moe': a state-scheduled (quasi-LPV) model can only be simulated step by step")
    traj, gates, alive = (sim.stepwise if stepwise else sim.affine)(as_t(z0))
    Y = traj.double().cpu().numpy() * fitted.y_scale + fitted.y_mean
    out = [Y[j, : lens[j]] * f_out[j] for j in range(S)]
    G_out = None if gates is None else [g[: lens[j]] for j, g in enumerate(gates.double().cpu().numpy())]
    return out, G_out, ~alive.cpu().numpy()


@dataclass
class _Sim:
    """One batched simulation: standardised padded inputs (S, L, n_u), steps H (S, L-1), envelope."""

    options: dict[str, Any]
    n_experts: int
    net: MixtureOfExperts
    U: torch.Tensor
    H: torch.Tensor
    lo: torch.Tensor
    hi: torch.Tensor
    d_scale: torch.Tensor
    si: list[int]
    ei: list[int]
    record_gate: bool
    lengths: np.ndarray | None = None
    """Samples per segment (rows past it are padding); None: every segment fills U."""
    fused: bool = True
    """One network call for the samples and the RK4 midpoints, products of 1 x 1 maps as elementwise
    products (exact); False: the former path (two network calls, matmuls), kept as the reference."""

    def _regressors(self, z: torch.Tensor | None, u: torch.Tensor) -> torch.Tensor:
        """[z; u_e; 1] (..., q); with ``z=None`` only the input part [u_e; 1]."""
        parts = [] if z is None else [z]
        parts.append(u[..., self.ei])
        if self.options["bias"]:
            parts.append(torch.ones_like(u[..., :1]))
        return torch.cat(parts, dim=-1)

    def _outputs(self, S: int, L: int, k: int) -> tuple[torch.Tensor, torch.Tensor | None]:
        traj = torch.empty((S, L, k), dtype=self.U.dtype, device=self.U.device)
        m = self.n_experts
        gates = torch.empty((S, L, m), dtype=self.U.dtype, device=self.U.device) if self.record_gate else None
        return traj, gates

    def stepwise(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """Any model (also quasi-LPV): the network is evaluated at every integrator stage
        (``numerics.integrate``); the gate, when recorded, along the simulated trajectory."""
        o = self.options

        def schedulers(zz: torch.Tensor, uu: torch.Tensor) -> torch.Tensor:
            return torch.cat([uu[..., self.si]] + ([zz] if o["scheduler_state"] else []), dim=-1)

        def rhs(zz: torch.Tensor, uu: torch.Tensor) -> torch.Tensor:
            G, _ = self.net.mixed(schedulers(zz, uu))
            return self.d_scale * torch.einsum("skq,sq->sk", G, self._regressors(zz, uu))

        S, L = self.U.shape[:2]
        lengths = np.full(S, L) if self.lengths is None else self.lengths
        traj, diverged = integrate(
            rhs, z, self.U, self.H, lengths, self.lo, self.hi, method=o["integrator"],
            inputs="hold" if o["input_interp"] == "hold" else "linear",
        )
        gates = self.net.gate(schedulers(traj, self.U)) if self.record_gate else None
        return traj, gates, ~diverged

    def _affine_parts(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """dz/dt = A z + w at inputs ``u`` (S, C, n_u): A (S, C, k, k), w (S, C, k), gate (S, C, M)."""
        G, alpha = self.net.mixed(u[..., self.si])
        k = G.shape[-2]
        A = self.d_scale[:, None] * G[..., :k]
        w = self.d_scale * torch.einsum("sckq,scq->sck", G[..., k:], self._regressors(None, u))
        return A, w, alpha

    def step_maps(self, a: int, b: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """LPV models: one RK4 or Euler step n -> n+1 (a <= n < b) is z' = Phi[n] z + gamma[n].

        Returns Phi (S, b-a, k, k), gamma (S, b-a, k) and the gate (S, b-a+1, M) at samples a..b.
        """
        o = self.options
        midpoints = o["integrator"] == "rk4" and o["input_interp"] != "hold"
        if self.fused and midpoints:  # samples a..b and the midpoints between them through the network at once
            n = b - a + 1
            u_mid = 0.5 * (self.U[:, a:b] + self.U[:, a + 1 : b + 1])
            A_all, w_all, alpha_all = self._affine_parts(torch.cat([self.U[:, a : b + 1], u_mid], dim=1))
            A, w, alpha = A_all[:, :n], w_all[:, :n], alpha_all[:, :n]
            mid: tuple[torch.Tensor, torch.Tensor] | None = (A_all[:, n:], w_all[:, n:])
        else:
            A, w, alpha = self._affine_parts(self.U[:, a : b + 1])  # at samples a..b
            mid = None
        k = A.shape[-1]
        mm = _matmul(k, self.fused)
        eye = torch.eye(k, dtype=A.dtype, device=A.device)
        h = self.H[:, a:b, None]
        A0, w0 = A[:, :-1], w[:, :-1]
        if o["integrator"] == "euler":
            return eye + h[..., None] * A0, h * w0, alpha
        if o["input_interp"] == "hold":
            Am, wm, A1, w1 = A0, w0, A0, w0
        else:
            Am, wm = mid if mid is not None else self._affine_parts(0.5 * (self.U[:, a:b] + self.U[:, a + 1 : b + 1]))[:2]
            A1, w1 = A[:, 1:], w[:, 1:]
        hh = h[..., None]
        mv = lambda M, x: mm(M, x[..., None])[..., 0]  # noqa: E731
        P1, q1 = A0, w0
        P2, q2 = mm(Am, eye + 0.5 * hh * P1), mv(Am, 0.5 * h * q1) + wm
        P3, q3 = mm(Am, eye + 0.5 * hh * P2), mv(Am, 0.5 * h * q2) + wm
        P4, q4 = mm(A1, eye + hh * P3), mv(A1, h * q3) + w1
        Phi = eye + hh / 6.0 * (P1 + 2 * P2 + 2 * P3 + P4)
        gamma = h / 6.0 * (q1 + 2 * q2 + 2 * q3 + q4)
        return Phi, gamma, alpha

    def rollout(self, z: torch.Tensor) -> torch.Tensor:
        """Differentiable open-loop trajectories (S, L, k) of an LPV model from ``z`` (S, k):
        no envelope, no divergence hold (for training on the simulation error)."""
        Phi, gamma, _ = self.step_maps(0, self.U.shape[1] - 1)
        M, c = affine_prefix_scan(Phi, gamma, fused=self.fused)
        mm = _matmul(z.shape[-1], self.fused)
        return torch.cat([z[:, None], mm(M, z[:, None, :, None])[..., 0] + c], dim=1)

    def affine(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """LPV models (schedulers free of the state): dz/dt = A(t) z + w(t), so one RK4 or Euler
        step is z' = Phi z + gamma with Phi, gamma computed for a whole chunk of steps at once;
        only the recurrence itself runs step by step."""
        (S, L, _), k = self.U.shape, z.shape[1]
        traj, gates = self._outputs(S, L, k)
        alive = torch.ones(S, dtype=torch.bool, device=z.device)
        traj[:, 0] = z
        width = S * self.n_experts * k * (k + len(self.ei) + 1) * 3
        chunk = int(np.clip(4_000_000 // max(width, 1), 16, max(L - 1, 16)))
        for a in range(0, L - 1, chunk):
            b = min(L - 1, a + chunk)
            Phi, gamma, alpha = self.step_maps(a, b)
            if gates is not None:
                gates[:, a : b + 1] = alpha
            part = torch.empty((S, b - a, k), dtype=z.dtype, device=z.device)
            zz = z
            if self.fused and k == 1:  # z' = phi z + gamma elementwise: the same products, no batched matmul
                phi, gam = Phi[:, :, 0], gamma
                for n in range(b - a):
                    zz = phi[:, n] * zz + gam[:, n]
                    part[:, n] = zz
            else:
                for n in range(b - a):
                    zz = (Phi[:, n] @ zz[..., None])[..., 0] + gamma[:, n]
                    part[:, n] = zz
            # divergence: keep the valid prefix of each segment, hold its last valid state after
            part, alive = hold_after_exit(part, z, alive, self.lo, self.hi)
            traj[:, a + 1 : b + 1] = part
            z = part[:, -1]
        return traj, gates, alive


def _matmul(k: int, fused: bool = True):
    """Product of (..., k, k) maps: for k = 1 (one target) an elementwise product, which is the
    same single multiplication per entry without a batched-matmul call; else ``torch.matmul``."""
    return torch.mul if fused and k == 1 else torch.matmul


def affine_prefix_scan(Phi: torch.Tensor, gamma: torch.Tensor, fused: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
    """All prefixes of the affine recurrence z_{n+1} = Phi_n z_n + gamma_n in log2(N) batched steps.

    ``Phi`` (S, N, k, k), ``gamma`` (S, N, k). Returns (M, c) with z_{n+1} = M_n z_0 + c_n. The
    maps compose associatively, (M2, c2) o (M1, c1) = (M2 M1, M2 c1 + c2), so a Hillis-Steele scan
    (doubling the reach each round) replaces N sequential steps; differentiable, for training on
    simulated windows. With one state (k = 1) and ``fused`` the products are elementwise (exact).
    """
    M, c = Phi, gamma
    d, N = 1, Phi.shape[1]
    mm = _matmul(Phi.shape[-1], fused)
    while d < N:
        M, c = (
            torch.cat([M[:, :d], mm(M[:, d:], M[:, :-d])], dim=1),
            torch.cat([c[:, :d], mm(M[:, d:], c[:, :-d, :, None])[..., 0] + c[:, d:]], dim=1),
        )
        d *= 2
    return M, c
