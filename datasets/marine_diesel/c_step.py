"""The marine-diesel physical model's fixed step in C: what ``export --fmu`` builds for ``pm`` on this data.

``simulate_runs`` (pm.py) is vectorised over time, but every part of it is causal and has a closed-form step
at the sample period dt: the fuel pump, turbocharger and thermocouple lags are first-order filters
(y = (1 - a) u + a y_prev, a = exp(-dt / tau), starting at rest on the first sample), the cycle and the
receiver are algebraic, and the steady charge pressure is the same bracketed secant (Illinois) per sample,
at most 40 iterations: a bounded cost per step. The C below follows pm.py's expressions operation by
operation (constants that pm.py computes from the parameters alone are computed here in Python, as there).
The secant runs on per sample until its step no longer moves x; pm.py stops a whole segment's solve once
every sample is within 1e-3 Pa of balance, which leaves most samples converged further and its slowest ones
to about 1e-8 relative. So the FMU reproduces the run's predictions to ``TOLERANCE`` (1e-8 relative; measured
on the small marine-diesel data's test part: 1.2e-9), not the 1e-9 of the closed-form linear models.

Internal states ``xs``: the lagged fuel, the lagged charge pressure and the two thermocouple temperatures.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from enginebench.datasets.marine_diesel import constants as C
from enginebench.datasets.marine_diesel.pm import P_CHARGE_MAX_PA, PM_NAME, RACK, SPEED, T_INLET, T_OUTLET

SOLVER_ITERATIONS = 40
SOLVER_TOL_PA = 1e-3
TOLERANCE = 1e-8
"""The export's accepted relative difference: pm.py stops its charge-pressure solve for a whole segment once
every sample is within 1e-3 Pa of balance, so its slowest sample's charge pressure (1e5 Pa and more) is exact
to about 1e-8 relative, and the temperatures with it; this step solves every sample to convergence."""


def _lag(tau: float, dt: float) -> tuple[float, float]:
    """(b0, a) of pm.py's first_order_lag; tau <= 0: no lag (b0 = 1, a = 0)."""
    if tau <= 0:
        return 1.0, 0.0
    a = float(np.exp(-dt / tau))
    return 1.0 - a, a


def constants(params: Mapping[str, Any], dt: float) -> dict[str, float]:
    """Every scalar the step needs, computed from the parameters as pm.py computes them."""
    p = {k: float(v) for k, v in params.items()}
    r, R, kap = p["compression_ratio"], p["r_gas"], p["kappa_cyl"]
    cv = R / (kap - 1.0)
    v1 = p["v_d_m3"] * r / (r - 1.0)
    t1, nc, ne = p["t1_k"], p["n_comp"], p["n_exp"]
    t2 = t1 * r ** (nc - 1.0)
    A2 = p["turbine_area_m2"] ** 2
    po = p["p_turbine_out_pa"]
    xa = (p["kappa_air"] - 1.0) / p["kappa_air"]
    xg = (p["kappa_gas"] - 1.0) / p["kappa_gas"]
    out = {
        "RACK_ZERO": p["rack_zero_pct"], "FUEL_NOM": p["fuel_nom_kg"], "N_MCR": p["n_mcr_rpm"], "R_GAS": R,
        "CV": cv, "CP": kap * cv, "V1": v1, "RT1": R * t1, "T2": t2, "R_NC": r ** nc, "R_CR": r,
        "ETA_HR_MCR": p["eta_hr_mcr"], "NEG_K_HR": -p["k_hr"], "LHV": p["lhv_j_per_kg"], "X_CV0": p["x_cv0"],
        "X_CV1": p["x_cv1"], "X_CP": p["x_cp"], "NE": ne, "NE1": ne - 1.0, "SCAV0": p["scavenge_ratio"],
        "SCAV1": p["scavenge_ratio_speed"], "KAP": kap, "KAP1": kap - 1.0, "T_CHARGE": p["t_charge_air_k"],
        "N_CYL": p["n_cyl"], "FOUR_A2": 4.0 * A2, "A2POPO": A2 * po * po, "TWO_A2": 2.0 * A2, "PO": po,
        "BAR": C.BAR, "ETA_TC0": p["eta_tc0"], "ETA_TC1": p["eta_tc1"], "ETA_TC2": p["eta_tc2"], "XG": xg,
        "INV_XA": 1.0 / xa, "CPG": p["cp_gas"], "CPA": p["cp_air"], "T_AMB": p["t_amb_k"], "P_AMB": p["p_amb_pa"],
        "P_MAX": P_CHARGE_MAX_PA, "ETA_TP0": p["eta_tp0"], "ETA_TP1": p["eta_tp1"], "BIAS_IN": p["bias_inlet_k"],
        "BIAS_OUT": p["bias_outlet_k"], "KELVIN": C.KELVIN, "TOL": SOLVER_TOL_PA,
    }
    for name, tau in (("F", "tau_fuel_s"), ("TC", "tau_tc_s"), ("TI", "tau_thermo_inlet_s"),
                      ("TO", "tau_thermo_outlet_s")):
        out[f"B_{name}"], out[f"A_{name}"] = _lag(p[tau], dt)
    return out


FUNCTIONS = r"""
static double clipd(double x, double lo, double hi) { return x < lo ? lo : (x > hi ? hi : x); }
static double maxd(double x, double lo) { return x < lo ? lo : x; }
static double mind(double x, double hi) { return x > hi ? hi : x; }

typedef struct { double m1, mc, alpha, beta, m_air, m_turb; } eb_cycle;

/* _cycle: modules B-D and the pressure-independent part of E (the terms the temperatures need) */
static eb_cycle eb_cyc(double speed, double fuel, double p1) {
    eb_cycle c;
    double n_rel = speed / N_MCR;
    c.m1 = p1 * V1 / RT1;
    c.mc = c.m1 + fuel;
    double eta_hr = mind(ETA_HR_MCR * pow(maxd(n_rel, 0.2), NEG_K_HR), 1.0);
    double q = eta_hr * fuel * LHV;
    double x_cv = clipd(X_CV0 + X_CV1 * n_rel, 0.0, 1.0);
    double q23 = x_cv * q;
    double q34 = X_CP * (q - q23);
    double q45 = q - q23 - q34;
    double p2 = p1 * R_NC;
    double t3 = T2 + q23 / (c.mc * CV);
    double p3 = p2 * t3 / T2;
    double t4 = t3 + q34 / (c.mc * CP);
    double ln54 = mind(q45 / (c.mc * R_GAS * t4), log(R_CR * t3 / t4));
    double exp_ratio = exp(ln54) * t4 / t3 / R_CR;
    double p5 = p3 * exp(-ln54);
    double t6 = t4 * pow(exp_ratio, NE1);
    double p6 = p5 * pow(exp_ratio, NE);
    double s = clipd(SCAV0 + SCAV1 * (n_rel - 1.0), 0.0, 0.6);
    double a_z = t6 / KAP;
    double b_z = t6 * KAP1 / (KAP * p6);
    double m_t = c.mc + s * c.m1;
    c.alpha = (c.mc * a_z + s * c.m1 * T_CHARGE) / m_t;
    c.beta = c.mc * b_z / m_t;
    double cps = N_CYL * speed / 120.0;
    c.m_air = c.m1 * (1.0 + s) * cps;
    c.m_turb = m_t * cps;
    return c;
}

/* _receiver: the turbine flow balance's closed-form root (p_d, T_d) */
static void eb_receiver(const eb_cycle *c, double *pd, double *td) {
    double m2R = c->m_turb * c->m_turb * R_GAS;
    double b = m2R * c->beta;
    *pd = (b + sqrt(b * b + FOUR_A2 * (A2POPO + m2R * c->alpha))) / TWO_A2;
    *td = c->alpha + c->beta * *pd;
}

/* _balance: the charge pressure the Buechi balance yields minus the one assumed */
static double eb_balance(double speed, double fuel, double p1) {
    eb_cycle c = eb_cyc(speed, fuel, p1);
    double pd, td;
    eb_receiver(&c, &pd, &td);
    double pb = p1 / BAR;
    double eta = clipd(ETA_TC0 + ETA_TC1 * pb + ETA_TC2 * pb * pb, 0.05, 0.95);
    double ratio = (c.m_turb * CPG * td) / (c.m_air * CPA * T_AMB);
    double rhs = eta * ratio * (1.0 - pow(PO / pd, XG));
    return P_AMB * pow(1.0 + maxd(rhs, 0.0), INV_XA) - p1;
}

/* solve_charge_pressure for one sample: bracketed secant, Illinois */
static double eb_charge_pressure(double speed, double fuel) {
    speed = maxd(speed, 1.0);
    fuel = maxd(fuel, 0.0);
    double a = P_AMB, b = P_MAX;
    double fa = eb_balance(speed, fuel, a), fb = eb_balance(speed, fuel, b);
    int saturated = fb >= 0.0;
    if (saturated) return P_MAX;
    fa = fa > 0.0 ? fa : 1e-9;
    double x = b;
    for (int it = 0; it < ITERATIONS; it++) {
        x = b - fb * (b - a) / (fb - fa);
        double fx = eb_balance(speed, fuel, x);
        if (fx * fb < 0.0) { a = b; fa = fb; } else { fa = fa * 0.5; }
        double moved = x - b;
        b = x;
        fb = fx;
        if (fabs(fx) < TOL && (fx == 0.0 || moved == 0.0 || fabs(moved) <= 4e-16 * fabs(x))) break;
    }
    return x;
}

/* the two thermocouple inputs at charge pressure p1: steady_outputs' turbine in- and outlet temperatures */
static void eb_temperatures(double speed, double fuel, double p1, double *t_in, double *t_out) {
    speed = maxd(speed, 1.0);
    fuel = maxd(fuel, 0.0);
    eb_cycle c = eb_cyc(speed, fuel, p1);
    double pd, td;
    eb_receiver(&c, &pd, &td);
    double eta_tp = maxd(ETA_TP0 + ETA_TP1 * p1 / BAR, 0.05);
    *t_in = td;
    *t_out = td * pow(PO / pd, eta_tp * XG);
}
"""

BODY = r"""
    double speed = uh[0], rack = uh[LU];
    double fuel_raw = FUEL_NOM * maxd(rack - RACK_ZERO, 0.0) / 100.0;
    double fuel = B_F * fuel_raw + A_F * (n == 0 ? fuel_raw : xs[0]);
    double p1s = eb_charge_pressure(speed, fuel);
    double p1 = B_TC * p1s + A_TC * (n == 0 ? p1s : xs[1]);
    double t_in, t_out;
    eb_temperatures(speed, fuel, p1, &t_in, &t_out);
    t_in = t_in - BIAS_IN;
    t_out = t_out - BIAS_OUT;
    double th_in = B_TI * t_in + A_TI * (n == 0 ? t_in : xs[2]);
    double th_out = B_TO * t_out + A_TO * (n == 0 ? t_out : xs[3]);
    xn[0] = fuel; xn[1] = p1; xn[2] = th_in; xn[3] = th_out;
    double temps[2] = {th_in - KELVIN, th_out - KELVIN};
%(outputs)s
"""


def c_model(params: Mapping[str, Any], dt: float, targets: Sequence[str], method: str = "pm") -> Any:
    """The ``CModel`` of the physical model with ``params`` at sample period ``dt`` (s), predicting ``targets``
    (turbine inlet and/or outlet exhaust temperature, degC) from engine speed and fuel rack."""
    from enginebench.errors import MethodError
    from enginebench.c_model import CModel, c_double

    known = (T_INLET, T_OUTLET)
    unknown = [t for t in targets if t not in known]
    if unknown or not targets:
        raise MethodError(f"{PM_NAME}: its C step predicts {', '.join(known)}, not {', '.join(unknown) or 'nothing'}")
    consts = constants(params, float(dt))
    defines = "".join(f"#define {k} {c_double(v)}\n" for k, v in consts.items())
    defines += f"#define ITERATIONS {SOLVER_ITERATIONS}\n"
    outputs = "\n".join(f"    ys[{j}] = temps[{known.index(t)}];" for j, t in enumerate(targets))
    return CModel(method=method, inputs=(SPEED, RACK), targets=tuple(targets), u_lags=1, y_lags=0,
                  body=BODY % {"outputs": outputs}, n_state=4, prelude=defines + FUNCTIONS, tolerance=TOLERANCE)
