"""The "true engine" of the marine-diesel generator: a mean-value model with maps.

It is deliberately richer than the physical model of egt-hybrid (sec. 4.2, our ``pm``),
in the pattern of the hardware-in-the-loop model of hil-diesel (sec. 2.1-2.3):

* compressor (after hil-diesel eqs. 3-7, our own parameterisation): speed lines
  m = m_max(U) (1 - (H / H_max(U))^2) in corrected flow, H = pi^((k-1)/k) - 1 the
  isentropic head, H_max proportional to the tip speed squared, m_max growing with it;
  efficiency a quadratic hill in (flow fraction, tip speed); fouling lowers it;
* air filter and intercooler pressure losses; intercooler effectiveness
  1 - exp(-NTU), NTU falling with air flow and with fouling (hil-diesel eq. 11);
* intake and exhaust receivers with filling dynamics dp/dt = R T / V (m_in - m_out)
  (hil-diesel eq. 12);
* volumetric efficiency depending on speed and on the scavenge pressure difference,
  plus valve-overlap scavenge air blown through to the exhaust (hil-diesel eq. 13-14);
* combustion efficiency falling at low load and at low air excess; gross indicated
  efficiency depending on air excess, speed and load; pumping work; friction mean
  effective pressure quadratic in speed (hil-diesel eqs. 17-21); attached pumps;
* heat to the cylinder walls; cylinder-outlet temperature from the cylinder energy
  balance; mixing with scavenge air; heat exchange with the exhaust-manifold wall, a
  thermal mass with its own state (minutes), insulated towards the engine room;
* turbine: flow law m = A p / sqrt(R T) sqrt(1 - pi^-k_t) with a mild speed effect,
  efficiency a parabola in the blade-speed ratio (a turbine map, unlike the PM); an
  exhaust waste gate opening with charge pressure bypasses gas around the turbine
  (more boost at part load, limited boost at full load);
* turbocharger rotor inertia, J w dw/dt = P_turbine - P_friction - P_compressor
  (hil-diesel eq. 10);
* a governor that meters fuel to deliver the demanded brake power, with rack and
  boost (smoke) limits, and a fast fuel actuator;
* first-order thermocouples on the exhaust temperatures (egt-hybrid eqs. 4-5 pattern).

Each bank (A, B) has its own turbocharger, receivers and thermocouples, with slightly
different constants. The integration uses a 1.5 s step (two steps per logged sample):
the receivers (time constants ~0.05 s, implicit Euler solved exactly) then act as
quasi-steady balances; the rotor (~2-5 s, linearly implicit), the manifold wall
(~100 s) and the thermocouples (~25-40 s) are true dynamics. The loop runs over time with numpy vectors over many
independent *lanes* (pieces of voyages, see ``simulate_rows``), so the cost is set by
the lane length, not by the size of the data set.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from enginebench.datasets.marine_diesel import constants as C
from enginebench.datasets.marine_diesel.components import (
    Compressor, Cylinders, GasExchange, Turbine, back_pressure, exhaust_receiver, governor, intake_receiver,
    intercooler, lag_step, manifold, peak_pressure, rotor_step, wall_step,
)
from enginebench.datasets.marine_diesel.engine_config import EngineConfig, fuel_to_rack, rack_to_fuel

BANKS = ("a", "b")

INPUT_NAMES = (
    "speed_rpm",        # engine speed, rpm
    "power_demand_w",   # brake power demanded by propeller and shaft, W
    "t_amb_k",          # compressor inlet (engine-room air) temperature, K
    "p_amb_pa",         # ambient pressure, Pa
    "t_coolant_k",      # LT water temperature at the intercooler inlet, K
    "foul_comp",        # compressor efficiency loss, fraction
    "foul_turb",        # turbine flow-area loss, fraction
    "foul_ic",          # intercooler NTU loss, fraction
)
"""Per-sample inputs of the engine loop."""

BANK_OUTPUTS = (
    "tc_speed_rpm", "p_im_pa", "t_im_k", "t_comp_out_k", "p_em_pa", "t_cyl_out_k",
    "t_turb_in_k", "t_turb_out_k", "tc_meas_in_k", "tc_meas_out_k", "tc_meas_cyl_k",
    "p_max_pa", "q_intercooler_w", "m_air_kg_s",
)
"""Per-bank outputs recorded at every logged sample (arrays of shape (2, n))."""

ENGINE_OUTPUTS = (
    "fuel_kg_cyc", "fuel_flow_kg_s", "brake_power_w", "friction_power_w", "aux_power_w",
    "wall_heat_w", "tc_friction_w", "manifold_loss_w", "unburnt_w", "lambda_trapped",
)
"""Engine-level outputs recorded at every logged sample (arrays of shape (n,))."""


# -- state and one integration step ----------------------------------------------------
class _Consts:
    """Per-bank constants as (2, 1) arrays, built once per run (cheap attribute access)."""

    def __init__(self, cfg: EngineConfig) -> None:
        for name, value in vars(cfg).items():
            setattr(self, name, np.asarray(value, dtype=float).reshape(2, 1) if isinstance(value, tuple) else value)
        self.vd_bank = C.N_CYL_BANK * C.V_D_CYL_M3


@dataclass
class _State:
    omega: np.ndarray      # (2, n) turbocharger speed, rad/s
    p_im: np.ndarray       # (2, n) intake receiver pressure, Pa
    p_em: np.ndarray       # (2, n) exhaust receiver pressure, Pa
    t_wall: np.ndarray     # (2, n) exhaust-manifold wall temperature, K
    m_comp: np.ndarray     # (2, n) compressor flow of the previous step, kg/s
    t_im: np.ndarray       # (2, n) intake temperature of the previous step, K
    fuel: np.ndarray       # (n,) fuel per cylinder per cycle, kg
    tc_in: np.ndarray      # (2, n) thermocouple temperatures, K
    tc_out: np.ndarray
    tc_cyl: np.ndarray
    diag: dict = field(default_factory=dict)


def _initial_state(u: dict[str, np.ndarray]) -> _State:
    """A rough start from the demanded load; the settling steps do the rest."""
    load = np.minimum(np.maximum(u["power_demand_w"] / C.P_MCR_W, 0.0), 1.15)
    ones = np.ones((2, load.shape[0]))
    p_amb = u["p_amb_pa"]
    speed = np.maximum(u["speed_rpm"], 50.0)
    fuel = (u["power_demand_w"] + 0.1 * C.P_MCR_W * speed / C.N_MCR_RPM) / (
        0.45 * C.LHV_J_PER_KG * C.N_CYL * speed / 120.0)
    t_wall = ones * (420.0 + 380.0 * load**0.3)
    return _State(omega=ones * (900.0 + 2300.0 * np.sqrt(load)), p_im=ones * (p_amb + 3.1e5 * load**0.9),
                  p_em=ones * (p_amb + 2.0e5 * load**0.9), t_wall=t_wall, m_comp=ones * (4.0 * load + 0.3),
                  t_im=ones * (u["t_coolant_k"] + 10.0), fuel=fuel, tc_in=t_wall + 50.0,
                  tc_out=t_wall - 50.0, tc_cyl=t_wall + 80.0)


def _step(st: _State, u: dict[str, np.ndarray], k: _Consts, steady: bool, record: bool) -> None:
    """Advance the state by one step of ``step_s`` seconds (in place), component by component.

    The receivers are integrated by implicit Euler, solved exactly by safeguarded
    Newton: first the intake receiver at the old exhaust pressure, then the exhaust
    receiver at the new intake pressure. The rotor (linearly implicit), the manifold
    wall and the thermocouples (exact first-order steps) follow with the flows and
    temperatures at the new pressures; the governor then sets the next fuel quantity.
    The equations live in ``components.py``.
    """
    h = k.step_s
    N = np.maximum(u["speed_rpm"], 50.0)
    n_rel = N / C.N_MCR_RPM
    n_cps = N / 120.0                                   # cycles per second per cylinder
    t_amb, p_amb = u["t_amb_k"], u["p_amb_pa"]
    omega, p_em_old = st.omega, st.p_em
    comp = Compressor.at(k, omega, st.m_comp, t_amb, p_amb)
    gx = GasExchange.at(k, n_rel, k.vd_bank * n_cps)

    # intake receiver, then compressor and intercooler at the new intake pressure
    p_im = intake_receiver(k, h, comp, gx, st.p_im, st.t_im, p_em_old, p_amb)
    m_c, _, ratio = comp.flow(p_im)
    t_c_out, p_comp = comp.outlet(k, m_c, ratio, t_amb, u["foul_comp"])
    t_im, q_ic = intercooler(k, m_c, t_c_out, u["t_coolant_k"], u["foul_ic"])

    # cylinders and turbine; exhaust receiver with the gas state at the old exhaust pressure
    fuel = st.fuel                                                   # (n,) kg per cylinder per cycle
    cyl = Cylinders.at(k, gx, p_im, t_im, fuel, n_rel, n_cps)
    p_aux = 0.5 * k.aux_power_mcr_w * n_rel**3
    turb = Turbine.at(k, omega, p_im, u["foul_turb"])
    cy0 = cyl.against(p_em_old)
    t_em0 = manifold(k, cy0, st.t_wall, t_amb, steady)[2]
    p_ta0 = back_pressure(k, p_amb, cy0["m_ex"])
    p_em = exhaust_receiver(k, h, gx, turb, p_im, t_im, cyl.m_f, p_em_old, t_em0, p_ta0)

    # everything at the new pressures
    cy = cyl.against(p_em)
    t_wall, q_gw, t_em = manifold(k, cy, st.t_wall, t_amb, steady)
    q_loss = k.em_wall_ua_ins_w_k * (t_wall - t_amb)
    m_out, m_t, p_turb, t_ta = turb.power(k, omega, p_em, t_em, back_pressure(k, p_amb, cy["m_ex"]))
    p_tcf = k.tc_friction_w_s2 * omega**2
    fmep = k.fmep_0_pa + k.fmep_2_pa * n_rel**2 + k.fmep_imep * cy["p_ig"] / gx.vdn
    p_fric = fmep * gx.vdn

    # rotor, wall, thermocouples
    st.omega = rotor_step(k, h, omega, p_turb, p_tcf, p_comp)
    st.p_im, st.p_em, st.m_comp, st.t_im = p_im, p_em, m_c, t_im
    if steady:
        st.t_wall = t_wall
        st.tc_in, st.tc_out, st.tc_cyl = t_em, t_ta, cy["t_cyl"]
    else:
        st.t_wall = wall_step(k, h, st.t_wall, q_gw, q_loss, cy["g_w"])
        st.tc_in = lag_step(st.tc_in, t_em, h, k.tau_tc_in_s)
        st.tc_out = lag_step(st.tc_out, t_ta, h, k.tau_tc_out_s)
        st.tc_cyl = lag_step(st.tc_cyl, cy["t_cyl"], h, k.tau_tc_cyl_s)

    if record:
        p_brake = cy["p_ig"] - cy["p_pump"] - p_fric - p_aux
        st.diag.update(
            tc_speed_rpm=omega / C.RPM_TO_RAD_S, p_im_pa=p_im, t_im_k=t_im, t_comp_out_k=t_c_out,
            p_em_pa=p_em, t_cyl_out_k=cy["t_cyl"], t_turb_in_k=t_em, t_turb_out_k=t_ta,
            p_max_pa=peak_pressure(k, p_im, t_im, cy, fuel, n_rel),
            q_intercooler_w=q_ic, m_air_kg_s=m_c, lambda_trapped=cy["lam"].mean(axis=0),
            fuel_kg_cyc=fuel, fuel_flow_kg_s=cyl.m_f.sum(axis=0), brake_power_w=p_brake.sum(axis=0),
            friction_power_w=p_fric.sum(axis=0), aux_power_w=2.0 * p_aux,
            wall_heat_w=cy["q_wall"].sum(axis=0), tc_friction_w=p_tcf.sum(axis=0),
            manifold_loss_w=q_loss.sum(axis=0), unburnt_w=(cyl.q_fuel - cy["q_burnt"]).sum(axis=0),
            tc_meas_in_k=st.tc_in, tc_meas_out_k=st.tc_out, tc_meas_cyl_k=st.tc_cyl,
            m_turb_kg_s=m_out, m_wastegate_kg_s=m_out - m_t, m_eng_kg_s=cy["m_tr"] + cy["m_sc"],
            p_turb_w=p_turb, p_comp_w=p_comp,
        )

    # governor: fuel for the demanded brake power; rack and boost limits; actuator lag
    st.fuel = governor(k, h, cy, p_fric, p_aux, n_cps, u["power_demand_w"], fuel, rack_to_fuel(k, 100.0, N))


def run_lanes(inputs: dict[str, np.ndarray], cfg: EngineConfig, *, settle_steps: int = 60,
              steady: bool = False) -> dict[str, np.ndarray]:
    """Simulate lanes of per-sample inputs, each (n_lanes, n_samples); outputs at every sample.

    Before the first sample every lane settles ``settle_steps`` steps at its first
    sample's inputs (turbocharger, receivers, governor) and then starts its wall and
    thermocouples at equilibrium. Within a sample the inputs move linearly from the
    previous sample's values (``cfg.substeps`` steps of ``cfg.step_s`` seconds).
    ``steady=True`` holds the wall and thermocouples at equilibrium throughout.
    Bank outputs have shape (2, n_lanes, n_samples), engine outputs (n_lanes, n_samples).
    """
    missing = [k for k in INPUT_NAMES if k not in inputs]
    if missing:
        raise KeyError(f"engine inputs lack {', '.join(missing)}")
    n_lanes, n_samples = inputs["speed_rpm"].shape
    u0 = {k: np.ascontiguousarray(inputs[k][:, 0], dtype=float) for k in INPUT_NAMES}
    consts = _Consts(cfg)
    st = _initial_state(u0)
    for _ in range(settle_steps):
        _step(st, u0, consts, steady=True, record=False)
    out_bank = {k: np.empty((2, n_lanes, n_samples)) for k in BANK_OUTPUTS}
    out_eng = {k: np.empty((n_lanes, n_samples)) for k in ENGINE_OUTPUTS}
    cols = {k: np.ascontiguousarray(inputs[k].T, dtype=float) for k in INPUT_NAMES}  # (n_samples, n_lanes)
    prev = u0
    m = cfg.substeps
    for i in range(n_samples):
        cur = {k: cols[k][i] for k in INPUT_NAMES}
        for j in range(1, m + 1):
            w = j / m
            u = cur if j == m else {k: prev[k] + w * (cur[k] - prev[k]) for k in INPUT_NAMES}
            _step(st, u, consts, steady=steady, record=(j == m))
        d = st.diag
        for k in BANK_OUTPUTS:
            out_bank[k][:, :, i] = d[k]
        for k in ENGINE_OUTPUTS:
            out_eng[k][:, i] = d[k]
        prev = cur
    return {**out_bank, **out_eng}


def steady_state(speed_rpm: np.ndarray, power_w: np.ndarray, cfg: EngineConfig | None = None, *,
                 t_amb_k: float = 298.15, p_amb_pa: float = 1.0e5, t_coolant_k: float = 305.15,
                 steps: int = 240) -> dict[str, np.ndarray]:
    """Steady operating points of the true engine (everything at equilibrium), one per entry.

    Also returns the turbine/compressor powers and flows needed for energy balances.
    """
    cfg = cfg or EngineConfig()
    speed = np.atleast_1d(np.asarray(speed_rpm, dtype=float))
    power = np.broadcast_to(np.asarray(power_w, dtype=float), speed.shape).copy()
    n = speed.size
    u = {
        "speed_rpm": speed, "power_demand_w": power, "t_amb_k": np.full(n, t_amb_k),
        "p_amb_pa": np.full(n, p_amb_pa), "t_coolant_k": np.full(n, t_coolant_k),
        "foul_comp": np.zeros(n), "foul_turb": np.zeros(n), "foul_ic": np.zeros(n),
    }
    consts = _Consts(cfg)
    st = _initial_state(u)
    for _ in range(steps - 1):
        _step(st, u, consts, steady=True, record=False)
    _step(st, u, consts, steady=True, record=True)
    out = dict(st.diag)
    out["rack_pct"] = fuel_to_rack(cfg, st.fuel, speed)
    return out


def lane_plan(starts: np.ndarray, stops: np.ndarray, lane_len: int, warmup: int) -> tuple[np.ndarray, np.ndarray]:
    """Cut runs [start, stop) of rows into lanes of ``lane_len`` kept rows plus ``warmup``.

    Returns ``index`` (n_lanes, warmup + lane_len) of row numbers (clamped to the run,
    so a lane at a run's start repeats its first row: the engine settles there) and
    ``keep`` (n_lanes, lane_len) of booleans marking rows that belong to the lane.
    """
    idx_rows, keep_rows = [], []
    offs = np.arange(-warmup, lane_len)
    for a, b in zip(starts, stops):
        firsts = np.arange(a, b, lane_len)
        if firsts.size == 0:
            continue
        pos = firsts[:, None] + offs[None, :]
        idx_rows.append(np.clip(pos, a, b - 1))
        keep_rows.append(pos[:, warmup:] < b)
    return np.concatenate(idx_rows), np.concatenate(keep_rows)


def simulate_rows(inputs: dict[str, np.ndarray], starts: np.ndarray, stops: np.ndarray,
                  cfg: EngineConfig, *, lane_len: int = 1200, warmup: int = 100,
                  batch_lanes: int = 1024,
                  progress: Callable[[float], None] | None = None) -> dict[str, np.ndarray]:
    """Simulate continuous runs of rows ([start, stop) each) given per-row inputs (n_rows,).

    Runs are cut into lanes simulated side by side; each lane first replays ``warmup``
    samples before its own rows, so that its state (time constants up to ~40 s for the
    thermocouples, ~100 s for the manifold wall) has forgotten the approximate start
    (warm-up of 300 s by default). Returns per-row arrays: bank outputs (2, n_rows),
    engine outputs (n_rows,).
    """
    n_rows = len(inputs["speed_rpm"])
    index, keep = lane_plan(np.asarray(starts), np.asarray(stops), lane_len, warmup)
    out = {k: np.empty((2, n_rows)) for k in BANK_OUTPUTS}
    out.update({k: np.empty(n_rows) for k in ENGINE_OUTPUTS})
    n_lanes = index.shape[0]
    for b0 in range(0, n_lanes, batch_lanes):
        sl = slice(b0, min(b0 + batch_lanes, n_lanes))
        idx = index[sl]
        res = run_lanes({k: np.asarray(inputs[k])[idx] for k in INPUT_NAMES}, cfg)
        rows = idx[:, warmup:][keep[sl]]
        for k in BANK_OUTPUTS:
            out[k][:, rows] = res[k][:, :, warmup:][:, keep[sl]]
        for k in ENGINE_OUTPUTS:
            out[k][rows] = res[k][:, warmup:][keep[sl]]
        if progress is not None:
            progress(sl.stop / n_lanes)
    return out
