"""Parameters of the synthetic helicopter: engines, fuel control (FADEC), rotor, airframe.

Units are per-unit where the dynamics are written per-unit: engine torque ``q`` is a
fraction of the maximum-continuous torque at 100 % power-turbine speed, fuel flow ``w``
a fraction of ``WF_REF``, rotor speed ``n`` a fraction of 100 % NR. Engine parameters are
arrays (one entry per engine) so that engine-to-engine scatter broadcasts over a batch.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

WF_REF = 300.0
"""kg/h: fuel flow at maximum-continuous power, sea-level ISA (w = 1)."""
P_REF = 850.0
"""kW: maximum-continuous power of one engine at 100 % NP (q = 1)."""


@dataclass(frozen=True)
class EngineParams:
    """Gas generator, power turbine and heat-soak parameters, one entry per engine.

    Steady state (corrected quantities, delta = P0/101.325 kPa, theta = T1/288.15 K):
    NG/sqrt(theta) = 100 (g0 + g1 wfe^gamma) %, power/(delta sqrt(theta)) =
    gain ((NGc - 60)/40)^2.2. ``wfe`` is the fuel that heats the gas; while the metal
    (state m, time constant tau_th) is colder than the gas, a fraction kappa of the
    fuel's step is soaked into the casing: the slow thermal mode.
    """

    fuel_scale: np.ndarray   # fuel this engine needs relative to the nominal engine
    g0: np.ndarray           # NG map offset
    g1: np.ndarray           # NG map slope
    gamma: np.ndarray        # NG map exponent
    gain: np.ndarray         # power map gain
    tau_g: np.ndarray        # s, gas-generator time constant at 100 % NGc, sea level
    tau_t: np.ndarray        # s, torque (gas path / power turbine) lag
    tau_th: np.ndarray       # s, heat-soak time constant at sea level
    kappa: np.ndarray        # fraction of a fuel step soaked into the metal at first
    nr_bias: np.ndarray      # %, bias of this FADEC's rotor-speed pick-up
    twist: np.ndarray        # % NP per unit torque change (shaft wind-up)
    tau_twist: np.ndarray    # s

    @property
    def n_engines(self) -> int:
        return int(np.asarray(self.fuel_scale).shape[0])

    def take(self, index: np.ndarray | list[int]) -> "EngineParams":
        """The parameters of engines ``index`` (to build a batch of any engine mix)."""
        idx = np.asarray(index)
        return replace(self, **{f.name: np.asarray(getattr(self, f.name))[idx] for f in fields(self)})


NOMINAL_ENGINE = dict(
    fuel_scale=1.0, g0=0.55, g1=0.45, gamma=0.6, gain=1.0, tau_g=0.75, tau_t=0.25,
    tau_th=45.0, kappa=0.07, nr_bias=0.0, twist=1.5, tau_twist=0.4,
)
"""Nominal engine; ``draw_engines`` scatters around it."""

_SCATTER = dict(  # (kind, size): 'rel' multiplies by 1 + size N(0,1), 'abs' adds size N(0,1)
    fuel_scale=("rel", 0.02), g0=("abs", 0.004), g1=("rel", 0.01), gamma=("rel", 0.01),
    gain=("rel", 0.02), tau_g=("rel", 0.08), tau_t=("rel", 0.08), tau_th=("rel", 0.10),
    kappa=("rel", 0.15), nr_bias=("abs", 0.05), twist=("rel", 0.10), tau_twist=("rel", 0.05),
)


def nominal_engines(n: int = 1) -> EngineParams:
    """``n`` identical nominal engines (no scatter)."""
    return EngineParams(**{k: np.full(n, float(v)) for k, v in NOMINAL_ENGINE.items()})


def draw_engines(rng: np.random.Generator, n: int = 2) -> EngineParams:
    """``n`` engines with small manufacturing scatter around the nominal engine."""
    values = {}
    for name, nominal in NOMINAL_ENGINE.items():
        kind, size = _SCATTER[name]
        z = np.clip(rng.standard_normal(n), -2.5, 2.5)
        values[name] = nominal * (1.0 + size * z) if kind == "rel" else nominal + size * z
    return EngineParams(**values)


@dataclass(frozen=True)
class FadecParams:
    """Fuel control law, the turboshaft-moe paper's eq. 2, identical software on both engines.

    w = s (kc-lead-lag(COL) + kp e + ki int(e) + kd de/dt), e = NR_ref - NR in %,
    s = delta sqrt(theta) schedules every gain on ambient conditions (corrected fuel
    flow). The lead-lag is (tau1 s + kc) / (tau2 s + 1) on the collective fraction.
    A slow torque-matching trim (km) shares the load between the two engines. Limits
    (scaled by s): w in [w_min, w_max], dw/dt in [-rate_down, rate_up] per second.
    """

    kp: float = 0.02
    ki: float = 0.012
    kd: float = 0.012
    tau_d: float = 0.15
    kc: float = 0.7
    tau1: float = 0.8
    tau2: float = 0.8
    km: float = 0.05
    w_min: float = 0.15
    w_max: float = 1.15
    rate_up: float = 0.15
    rate_down: float = 0.25


@dataclass(frozen=True)
class RotorParams:
    """Main-rotor inertia and the rotor's torque as a function of collective.

    Load (sum of both engines' per-unit torque) at rotor speed n, density ratio sigma,
    advance ratio mu and collective fraction c:
    q_load = n^2 sigma (a0 (1 + 4.65 mu^2) + a1 c + a2 c^2) / P_REF, with a0..a2 in kW.
    dn/dt = (q1 + q2 - q_load) / t_m.
    """

    t_m: float = 7.0          # s, J Omega^2 / P_REF
    a0: float = 200.0         # kW, blade profile power at zero collective, hover
    a1: float = 1000.0        # kW per unit collective
    a2: float = 900.0         # kW per unit collective squared
    tip_speed: float = 220.0  # m/s at 100 % NR


@dataclass(frozen=True)
class AirframeParams:
    """Power required in flight (momentum theory + profile + parasite + climb), in kW."""

    disk_area: float = 150.0   # m^2
    k_induced: float = 1.15
    profile_kw: float = 200.0  # at sea level, hover
    flat_plate: float = 2.5    # m^2 equivalent drag area
    transmission: float = 0.95
    accessories_kw: float = 20.0
    ground_effect: float = 0.85  # induced power factor in ground effect
    descent_factor: float = 0.75  # share of W Vz recovered in descent
