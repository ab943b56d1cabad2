"""Flight profiles: a sequence of manoeuvres turned into 12 Hz exogenous signals.

A flight starts and ends on the ground (flat pitch, low power), takes off through an
in-ground-effect hover and a climb, then strings random manoeuvres — cruise at several
airspeeds, turns, climbs, descents, low-power descents, hovers out of and in ground
effect — keeping altitude within an envelope. Targets are smoothed by cascaded lags
(accelerations of a few knots per second), altitude integrates the climb rate, the
atmosphere (ISA + a per-flight temperature offset) gives intake pressure and
temperature, and the pilot's collective is the one that makes the rotor absorb the
power required, plus the pilot's small corrections. Turbulence perturbs the rotor load.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from enginebench.datasets.turboshaft.atmosphere import RHO_SL, intake, isa
from enginebench.datasets.turboshaft.engine import ambient_ratios, ng_steady, torque_steady
from enginebench.datasets.turboshaft.params import AirframeParams, FadecParams, RotorParams, nominal_engines
from enginebench.datasets.turboshaft.rotor import collective_for, load, power_required

PHASES = ("ground", "hover", "climb", "cruise", "turn", "descent", "low-power")
"""Manoeuvre names; ``FlightProfile.phase`` holds indices into this tuple."""
GROUND, HOVER, CLIMB, CRUISE, TURN, DESCENT, LOW_POWER = range(len(PHASES))
CRUISE_SPEEDS_KN = (70.0, 90.0, 110.0, 125.0, 140.0)
MAX_PRESSURE_ALTITUDE = 3000.0
MIN_AGL = 150.0


@dataclass(frozen=True)
class FlightProfile:
    """One flight's exogenous signals at 12 Hz (all arrays of the same length).

    ``col`` is the collective fraction 0..1, ``airspeed`` kn, ``altitude`` pressure
    altitude m, ``p0`` kPa, ``t1`` K, ``rho`` kg/m^3, ``nr_ref`` %, ``load_factor`` the
    turbulence factor on rotor load, ``phase`` the manoeuvre index (``PHASES``) and
    ``phase_age`` the seconds since that manoeuvre began.
    """

    flight: str
    dt: float
    col: np.ndarray
    airspeed: np.ndarray
    altitude: np.ndarray
    p0: np.ndarray
    t1: np.ndarray
    rho: np.ndarray
    nr_ref: np.ndarray
    load_factor: np.ndarray
    phase: np.ndarray
    phase_age: np.ndarray

    def __len__(self) -> int:
        return len(self.col)


def lag(x: np.ndarray, tau: float, dt: float, order: int = 1) -> np.ndarray:
    """``order`` cascaded first-order lags of time constant ``tau``, starting at rest at x[0]."""
    a = np.exp(-dt / tau)
    y = np.asarray(x, dtype=np.float64)
    for _ in range(order):
        y, _ = lfilter([1.0 - a], [1.0, -a], y, zi=[a * y[0]])
    return y


def ar1(rng: np.random.Generator, n: int, sd: float, tau: float, dt: float) -> np.ndarray:
    """Stationary first-order autoregressive noise: standard deviation ``sd``, correlation time ``tau``."""
    a = np.exp(-dt / tau)
    e = rng.standard_normal(n) * sd * np.sqrt(1.0 - a * a)
    y, _ = lfilter([1.0], [1.0, -a], e, zi=[a * sd * rng.standard_normal()])
    return y


def _manoeuvres(rng: np.random.Generator, duration: float, elevation: float) -> list[tuple]:
    """The manoeuvre list of one flight: (phase, seconds, airspeed kn, climb m/s, bank deg, in ground effect).

    Loops over manoeuvres (tens per flight), not samples. Climbs and descents are sized
    by the altitude change they make, keeping the flight inside the envelope.
    """
    ceiling = MAX_PRESSURE_ALTITUDE - elevation
    plan: list[tuple] = []
    agl = 0.0
    speed = 0.0

    def add(phase: int, seconds: float, v: float, vz: float = 0.0, bank: float = 0.0, ige: float = 0.0) -> None:
        nonlocal agl, speed
        plan.append((phase, float(seconds), float(v), float(vz), float(bank), float(ige)))
        agl = max(0.0, agl + vz * seconds)
        speed = v

    def leg(dh: float, v: float, rate: float, phase: int) -> None:
        add(phase, abs(dh) / rate, v, np.sign(dh) * rate)

    add(GROUND, rng.uniform(60, 120), 0.0)
    add(HOVER, rng.uniform(20, 60), 0.0, ige=1.0)
    leg(min(rng.uniform(300, 900), ceiling - 100), rng.uniform(60, 80), rng.uniform(3, 6), CLIMB)

    def time_used() -> float:
        return sum(p[1] for p in plan)

    def landing_time() -> float:
        return agl / 3.0 + 150.0

    while time_used() + landing_time() < duration:
        u = rng.random()
        if u < 0.30:
            add(CRUISE, rng.uniform(40, 300), rng.choice(CRUISE_SPEEDS_KN))
        elif u < 0.45:
            v = speed if speed >= 60 else rng.choice(CRUISE_SPEEDS_KN[1:3])
            add(TURN, rng.uniform(15, 60), v, bank=rng.choice([-1.0, 1.0]) * rng.uniform(15, 35))
        elif u < 0.58:
            room = ceiling - 100 - agl
            if room > 150:
                leg(rng.uniform(150, min(800, room)), rng.uniform(60, 90), rng.uniform(2.5, 7), CLIMB)
        elif u < 0.71:
            room = agl - MIN_AGL
            if room > 150:
                leg(-rng.uniform(150, min(800, room)), rng.uniform(60, 120), rng.uniform(2, 6), DESCENT)
        elif u < 0.82:
            room = agl - MIN_AGL
            if room > 250:
                leg(-rng.uniform(200, min(900, room)), rng.uniform(55, 80), rng.uniform(7, 12), LOW_POWER)
        elif u < 0.92:
            if elevation + agl < 2200:
                add(HOVER, rng.uniform(20, 90), 0.0)
        else:  # low hover in ground effect and climb out again
            if agl > 20:
                leg(-(agl - 10), 50.0, 3.0, DESCENT)
            add(HOVER, rng.uniform(20, 60), 0.0, ige=1.0)
            leg(min(rng.uniform(300, 900), ceiling - 100) - agl, rng.uniform(60, 80), rng.uniform(3, 6), CLIMB)
    if agl > 10:
        leg(-(agl - 10), 50.0, 3.0, DESCENT)
    add(HOVER, rng.uniform(15, 45), 0.0, ige=1.0)
    if agl > 0:
        add(HOVER, agl / 1.0, 0.0, -1.0, ige=1.0)  # vertical touch-down at 1 m/s
    rest = max(duration - time_used(), 0.0)
    add(GROUND, rest + rng.uniform(30, 60), 0.0)
    return plan


def make_flight(
    rng: np.random.Generator,
    flight: str,
    duration: float,
    dt: float = 1.0 / 12.0,
    rotor: RotorParams | None = None,
    air: AirframeParams | None = None,
    fadec: FadecParams | None = None,
) -> FlightProfile:
    """A random flight lasting at least ``duration`` seconds (whole manoeuvres)."""
    rotor = rotor or RotorParams()
    air = air or AirframeParams()
    fadec = fadec or FadecParams()
    elevation = rng.uniform(0.0, 1200.0)
    dT = rng.uniform(-15.0, 25.0)
    dp = rng.normal(0.0, 0.8)
    mass0 = rng.uniform(5200.0, 6800.0)
    high_nr = rng.random() < 0.4
    turbulence = rng.uniform(0.004, 0.02)

    plan = _manoeuvres(rng, duration, elevation)
    counts = np.array([max(1, int(round(p[1] / dt))) for p in plan])
    table = np.array([p[:1] + p[2:] for p in plan])  # phase, v, vz, bank, ige
    phase = np.repeat(table[:, 0].astype(np.int8), counts)
    n = len(phase)
    starts = np.repeat(np.cumsum(counts) - counts, counts)
    phase_age = (np.arange(n) - starts) * dt

    v = lag(np.repeat(table[:, 1], counts), 7.0, dt, order=2)
    vz = lag(np.repeat(table[:, 2], counts), 2.5, dt, order=2)
    bank = lag(np.repeat(table[:, 3], counts), 2.0, dt, order=2)
    ige = lag(np.repeat(table[:, 4], counts), 3.0, dt)
    on_ground = lag((phase == GROUND).astype(np.float64), 3.0, dt, order=2)
    agl = np.maximum(np.cumsum(vz) * dt, 0.0)
    altitude = elevation + agl
    in_flight = 1.0 - on_ground
    gust = ar1(rng, n, 1.5, 3.0, dt) * in_flight
    airspeed = np.maximum(v + gust, 0.0)

    p, t, rho = isa(altitude, dT, dp)
    p0, t1 = intake(p, t, rho, airspeed)
    sigma = rho / RHO_SL
    nr_mode = np.isin(phase, (HOVER, CLIMB)) & (agl < 300) if high_nr else np.zeros(n, dtype=bool)
    nr_ref = lag(np.where(nr_mode, 102.0, 100.0), 4.0, dt)
    nr = nr_ref / 100.0

    mass = mass0 - 0.16 * np.arange(n) * dt
    q_req = power_required(airspeed, vz, bank, mass, rho, ige, rotor, air)
    delta, theta, _ = ambient_ratios(p0, t1)
    nominal = nominal_engines(1)
    available = 2.0 * torque_steady(ng_steady(fadec.w_max, theta, nominal), nr, delta, theta, nominal)
    q_hi = np.minimum(load(0.95, nr, sigma, airspeed, rotor), 0.85 * available)
    q_lo = load(0.05, nr, sigma, airspeed, rotor)
    c_air = collective_for(np.clip(q_req, q_lo, q_hi), nr, sigma, airspeed, rotor)
    c_ground = rng.uniform(0.02, 0.05)
    pilot = (ar1(rng, n, 0.006, 2.0, dt) + ar1(rng, n, 0.002, 0.3, dt)) * in_flight
    col = np.clip(on_ground * c_ground + in_flight * c_air + pilot, 0.0, 1.0)
    load_factor = 1.0 + turbulence * ar1(rng, n, 1.0, 1.0, dt) * in_flight

    return FlightProfile(
        flight=flight, dt=dt, col=col, airspeed=airspeed, altitude=altitude, p0=p0, t1=t1, rho=rho,
        nr_ref=nr_ref, load_factor=load_factor, phase=phase, phase_age=phase_age,
    )
