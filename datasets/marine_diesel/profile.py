"""The vessel's operational profile: voyages, combinator modes, load, sea and fouling.

The egt-hybrid paper (sec. 3, sec. 5.1 and Fig. 7) describes a twin-shaft patrol vessel with
controllable-pitch propellers (CPP) and one diesel per shaft, run on two combinator
curves: *transit* (higher pitch, lower speed, slow acceleration) and *manoeuvre* (low
pitch, high speed, fast acceleration), with speeds well below the FAT's 630 rpm and
loads below the propeller law for much of the time. This module draws such a life:

* voyages separated by port stays (engine off, not logged); each voyage is a sequence
  of legs: a harbour manoeuvre at departure, transit legs, patrol manoeuvre legs and a
  harbour manoeuvre at arrival;
* within a leg, the bridge lever is held for random times at random positions and
  moved at a mode-dependent rate (a rate limiter: slow in transit, fast in manoeuvre);
* the combinator curve of the mode maps the lever to engine speed set-point and pitch;
  the governor (speed) and the pitch actuator follow with short lags;
* propeller load: P = P_MCR (N / N_MCR)^3 k_Q, with a torque factor k_Q growing with
  pitch and with the advance-ratio deficit while the ship (a first-order lag of about
  100 s) has not caught up, plus leg-wise sea margin, wave-induced fluctuation, shaft
  acceleration power and slowly growing hull fouling;
* environment: seawater temperature with a seasonal cycle, regional offsets per voyage
  and a daily ripple; engine-room air following seawater and load; ambient pressure
  drifting with the weather;
* engine fouling over running hours: compressor (washed in port every ~250 running
  hours), turbine nozzle and intercooler (not cleaned within the data set);
* logging gaps: random drop-outs of the logger (the engine keeps running; the rows are
  marked unlogged and the segment ends).

All draws come from the ``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from enginebench.datasets.marine_diesel import constants as C
from enginebench.datasets.marine_diesel.sensors import ar1_noise, first_order_lag

# -- combinator curves (lever 0..1) ----------------------------------------------------
TRANSIT_SPEED_START = 0.35
"""Transit mode: lever position where engine speed starts to rise above idle."""
TRANSIT_PITCH_FULL = 0.45
"""Transit mode: lever position where pitch reaches TRANSIT_PITCH_LOW."""
TRANSIT_PITCH_LOW = 0.8
"""Transit mode: pitch (fraction of design) while the speed is at idle; design pitch at MCR."""
MANOEUVRE_SPEED_MIN_RPM = 620.0
"""Manoeuvre mode: engine speed at lever 0, rpm (high speed ready for fast response)."""
MANOEUVRE_PITCH_MAX = 0.75
"""Manoeuvre mode: pitch at full lever, fraction of design pitch."""
LEVER_RATE_TRANSIT = 0.0012
"""Lever rate limit in transit, 1/s (full range in about 14 min)."""
LEVER_RATE_MANOEUVRE = 0.015
"""Lever rate limit in manoeuvre, 1/s (full range in about 67 s)."""
TAU_SETPOINT_S = 10.0
"""Smoothing of the combinator output at mode changes, s."""
TAU_GOVERNOR_S = 4.0
"""Engine speed following its set-point (governor and shaft), s."""
TAU_PITCH_S = 5.0
"""Pitch actuator, s."""
TAU_SHIP_S = 100.0
"""Ship speed following its steady value, s."""
SHAFT_INERTIA_KG_M2 = 1500.0
"""Shaft-line inertia referred to the engine shaft, kg m^2."""
KQ_ZERO_PITCH = 0.10
"""Propeller torque factor at zero pitch (fraction of design)."""
KQ_ADVANCE = 0.8
"""Torque factor gain on the advance-ratio deficit."""
P_DEMAND_MAX = 1.12
"""Load limiter: highest brake power demand, fraction of MCR."""

# -- voyage plan (ranges of uniform draws unless said otherwise) ----------------------------
HARBOUR_HOURS = (0.4, 1.2)
"""Harbour manoeuvre at departure and at arrival, h."""
TRANSIT_LEG_HOURS = (1.5, 8.0)
PATROL_LEG_HOURS = (0.3, 2.5)
PATROL_PROBABILITY = 0.6
"""Chance of a patrol (manoeuvre) leg after each transit leg."""
HOLD_MANOEUVRE_S = (180.0, 30.0, 900.0)
"""Lever hold time in manoeuvre: exponential mean, clipped to [min, max], s."""
HOLD_TRANSIT_S = (2700.0, 600.0, 10800.0)
"""Lever hold time in transit: exponential mean, clipped to [min, max], s."""
LEVER_TRANSIT = (0.45, 0.95)
LEVER_MANOEUVRE = (0.1, 1.0)
IDLE_PROBABILITY = 0.25
"""Chance that a manoeuvre command is near idle (lever below IDLE_LEVER)."""
IDLE_LEVER = 0.1
FINAL_IDLE_S = 300.0
"""The lever returns to idle this long before a voyage ends, s."""
GAP_EVERY_HOURS = 14.0
"""Mean running time between logging gaps (Poisson), h."""
GAP_SECONDS = (60.0, 2400.0)
PORT_HOURS = (10.0, 60.0)
SEA_MARGIN = (0.0, 0.12)
"""Added resistance of a leg from sea state and wind, fraction."""
SPEED_RIPPLE_RPM = (0.5, 20.0)
"""Wave-induced speed ripple: rpm in calm water, plus rpm per unit of sea margin."""
WAVE_LOAD = (0.01, 0.15)
"""Wave-induced load fluctuation: relative sd in calm water, plus per unit of sea margin."""
TAU_SPEED_RIPPLE_S = 6.0
TAU_WAVES_S = 4.0
TAU_SEA_S = 1800.0
"""Sea margin changes between legs over this time, s."""
TAU_ENGINE_ROOM_S = 1200.0
"""Engine-room air warming with load, s."""

# -- environment and fouling ------------------------------------------------------------
SEAWATER_MEAN_C = 14.0
SEAWATER_SEASONAL_C = 6.0
SEAWATER_DIURNAL_C = 0.4
SEAWATER_VOYAGE_SD_C = 1.5
ENGINE_ROOM_ABOVE_SEA_C = 9.0
ENGINE_ROOM_LOAD_C = 7.0
P_AMB_MEAN_PA = 1.013e5
P_AMB_SD_PA = 900.0
P_AMB_TAU_S = 36 * 3600.0
COMP_FOUL_PER_HOUR = 1.0e-4
"""Compressor efficiency loss per running hour since the last wash (3 % after 300 h)."""
COMP_WASH_HOURS = 250.0
TURB_FOUL_FULL = 0.04
"""Turbine flow-area loss after FULL_HOURS running hours."""
IC_FOUL_FULL = 0.10
"""Intercooler NTU loss after FULL_HOURS running hours."""
HULL_FOUL_PER_YEAR = 0.12
"""Added resistance from hull fouling per calendar year (fraction)."""


@dataclass(frozen=True)
class Profile:
    """Per-row operating conditions of the whole synthetic life (logged or not)."""

    dt: float
    time_s: np.ndarray
    voyage: np.ndarray
    logged: np.ndarray
    manoeuvre: np.ndarray
    lever: np.ndarray
    speed_ref_rpm: np.ndarray
    speed_rpm: np.ndarray
    pitch: np.ndarray
    ship_speed: np.ndarray
    power_demand_w: np.ndarray
    seawater_k: np.ndarray
    engine_room_k: np.ndarray
    p_amb_pa: np.ndarray
    foul_comp: np.ndarray
    foul_turb: np.ndarray
    foul_ic: np.ndarray
    hull: np.ndarray
    running_hours: np.ndarray

    @property
    def voyage_starts(self) -> np.ndarray:
        return np.r_[0, np.flatnonzero(np.diff(self.voyage)) + 1]

    @property
    def voyage_stops(self) -> np.ndarray:
        return np.r_[self.voyage_starts[1:], len(self.voyage)]

    def __len__(self) -> int:
        return len(self.time_s)


def transit_combinator(lever: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Transit mode: pitch first (to 80 % at lever 0.45), then speed from idle to MCR with pitch to 100 %.

    Below full speed the pitch stays under design, so the engine runs below the
    propeller law at low speed, as the egt-hybrid paper's vessel does (sec. 5.1).
    """
    frac = np.clip((lever - TRANSIT_SPEED_START) / (1.0 - TRANSIT_SPEED_START), 0.0, 1.0)
    speed = C.N_IDLE_RPM + (C.N_MCR_RPM - C.N_IDLE_RPM) * frac
    pitch = np.clip(lever / TRANSIT_PITCH_FULL, 0.0, 1.0) * (TRANSIT_PITCH_LOW + (1.0 - TRANSIT_PITCH_LOW) * frac)
    return speed, pitch


def manoeuvre_combinator(lever: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Manoeuvre mode: high speed at low pitch, speed to the top of the range at full lever."""
    speed = MANOEUVRE_SPEED_MIN_RPM + (C.N_MAX_RPM - MANOEUVRE_SPEED_MIN_RPM) * np.clip(lever, 0.0, 1.0) ** 0.8
    return speed, MANOEUVRE_PITCH_MAX * np.clip(lever, 0.0, 1.0)


def propeller_power(speed_rpm: np.ndarray, pitch: np.ndarray, advance: np.ndarray) -> np.ndarray:
    """Brake power absorbed by the CPP and gearbox in calm water, clean hull, W.

    k_Q = q0 + (1 - q0) pitch^1.5 + q_J pitch (J_design(pitch) - J), with J the advance
    ratio relative to design and J_design(pitch) = pitch^0.8 its steady value for a
    clean hull; k_Q = 1 at design pitch and steady speed.
    """
    kq = (KQ_ZERO_PITCH + (1.0 - KQ_ZERO_PITCH) * pitch**1.5
          + KQ_ADVANCE * pitch * (pitch**0.8 - advance))
    kq = np.maximum(kq, 0.2 * KQ_ZERO_PITCH)
    return C.P_MCR_W * (speed_rpm / C.N_MCR_RPM) ** 3 * kq


# -- the voyage plan (a short Python loop over voyages, legs and lever commands) ------------
@dataclass
class _Voyage:
    start_s: float
    n: int
    legs: list          # (first row, mode is manoeuvre, sea margin)
    commands: list      # (row, lever)
    gaps: list          # (first row, stop row) of logging gaps
    sea_offset_c: float


def _plan_voyage(rng: np.random.Generator, start_s: float, hours: float, dt: float, sea_offset: float) -> _Voyage:
    n = int(round(hours * 3600.0 / dt))
    legs, commands = [], []
    t = 0.0
    total = hours * 3600.0
    dep = rng.uniform(*HARBOUR_HOURS) * 3600.0
    arr = rng.uniform(*HARBOUR_HOURS) * 3600.0
    plan = [(True, dep)]
    left = total - dep - arr
    while left > 0:
        d = min(rng.uniform(*TRANSIT_LEG_HOURS) * 3600.0, left)
        plan.append((False, d))
        left -= d
        if left > 0 and rng.random() < PATROL_PROBABILITY:
            d = min(rng.uniform(*PATROL_LEG_HOURS) * 3600.0, left)
            plan.append((True, d))
            left -= d
    plan.append((True, arr))
    for manoeuvre, dur in plan:
        row0 = int(t / dt)
        legs.append((row0, manoeuvre, rng.uniform(*SEA_MARGIN)))
        tc, end = t, t + dur
        while tc < end:
            if manoeuvre:
                idle = rng.random() < IDLE_PROBABILITY
                level = rng.uniform(0.0, IDLE_LEVER) if idle else rng.uniform(*LEVER_MANOEUVRE)
                mean, lo, hi = HOLD_MANOEUVRE_S
            else:
                level = rng.uniform(*LEVER_TRANSIT)
                mean, lo, hi = HOLD_TRANSIT_S
            hold = np.clip(rng.exponential(mean), lo, hi)
            commands.append((int(tc / dt), level))
            tc += hold
        t = end
    commands.append((max(n - int(FINAL_IDLE_S / dt), 0), 0.0))      # back to idle before stopping
    gaps = []
    for _ in range(rng.poisson(hours / GAP_EVERY_HOURS)):
        a = int(rng.integers(0, max(n - 1, 1)))
        gaps.append((a, min(n, a + int(rng.uniform(*GAP_SECONDS) / dt))))
    return _Voyage(start_s=start_s, n=n, legs=legs, commands=sorted(commands), gaps=gaps, sea_offset_c=sea_offset)


def _rate_limited(n: int, commands: list, rate_per_row: np.ndarray) -> np.ndarray:
    """Lever position: piecewise-constant commands followed at a limited rate (row units)."""
    out = np.empty(n)
    value = commands[0][1] if commands else 0.0
    bounds = [c[0] for c in commands] + [n]
    for (row, target), stop in zip(commands, bounds[1:]):
        row, stop = min(row, n), min(stop, n)
        if stop <= row:
            continue
        steps = np.arange(1, stop - row + 1)
        step = rate_per_row[row]
        delta = np.clip(target - value, -step * steps, step * steps)
        out[row:stop] = value + delta
        value = out[stop - 1]
    return out


def make_profile(hours: float, rng: np.random.Generator, dt: float = C.DT_LOG_S,
                 voyage_hours: tuple[float, float] = (12.0, 60.0)) -> Profile:
    """Draw voyages until ``hours`` of logged data exist; the last voyage is cut to fit."""
    target_rows = int(round(hours * 3600.0 / dt))
    day0 = rng.uniform(0.0, 365.0)
    voyages: list[_Voyage] = []
    t_abs, logged_rows = 0.0, 0
    while logged_rows < target_rows:
        v = _plan_voyage(rng, t_abs, rng.uniform(*voyage_hours), dt, rng.normal(0.0, SEAWATER_VOYAGE_SD_C))
        mask = np.ones(v.n, dtype=bool)
        for a, b in v.gaps:
            mask[a:b] = False
        need = target_rows - logged_rows
        if mask.sum() > need:                                    # cut the last voyage
            v.n = int(np.searchsorted(np.cumsum(mask), need) + 1)
            v.gaps = [(a, min(b, v.n)) for a, b in v.gaps if a < v.n]
            v.legs = [leg for leg in v.legs if leg[0] < v.n]
            v.commands = [c for c in v.commands if c[0] < v.n]
            mask = mask[: v.n]
        logged_rows += int(mask.sum())
        voyages.append(v)
        t_abs += v.n * dt + rng.uniform(*PORT_HOURS) * 3600.0     # port stay

    n_tot = sum(v.n for v in voyages)
    voyage = np.repeat(np.arange(len(voyages)), [v.n for v in voyages])
    starts = np.r_[0, np.cumsum([v.n for v in voyages])[:-1]]
    local = np.arange(n_tot) - starts[voyage]
    time_s = np.array([v.start_s for v in voyages])[voyage] + local * dt

    manoeuvre = np.empty(n_tot, dtype=bool)
    sea = np.empty(n_tot)
    lever = np.empty(n_tot)
    logged = np.ones(n_tot, dtype=bool)
    for i, v in enumerate(voyages):
        s = starts[i]
        bounds = [leg[0] for leg in v.legs] + [v.n]
        for (row, man, margin), stop in zip(v.legs, bounds[1:]):
            manoeuvre[s + row: s + stop] = man
            sea[s + row: s + stop] = margin
        rate = np.where(manoeuvre[s: s + v.n], LEVER_RATE_MANOEUVRE, LEVER_RATE_TRANSIT) * dt
        lever[s: s + v.n] = _rate_limited(v.n, v.commands, rate)
        for a, b in v.gaps:
            logged[s + a: s + b] = False

    # combinator, governor, pitch actuator, ship
    n_t, p_t = transit_combinator(lever)
    n_m, p_m = manoeuvre_combinator(lever)
    speed_ref = first_order_lag(np.where(manoeuvre, n_m, n_t), TAU_SETPOINT_S, dt, starts)
    pitch = first_order_lag(np.where(manoeuvre, p_m, p_t), TAU_PITCH_S, dt, starts)
    speed = first_order_lag(speed_ref, TAU_GOVERNOR_S, dt, starts)
    ripple = SPEED_RIPPLE_RPM[0] + SPEED_RIPPLE_RPM[1] * sea
    speed = speed + ar1_noise(n_tot, 1.0, TAU_SPEED_RIPPLE_S, dt, rng, starts) * ripple
    n_rel = speed / C.N_MCR_RPM

    # fouling and environment
    hours_run = (np.arange(n_tot) + 1) * dt / 3600.0
    since_wash = np.empty(n_tot)
    last_wash = 0.0
    for i, v in enumerate(voyages):
        h0 = starts[i] * dt / 3600.0
        if h0 - last_wash >= COMP_WASH_HOURS:
            last_wash = h0
        since_wash[starts[i]: starts[i] + v.n] = hours_run[starts[i]: starts[i] + v.n] - last_wash
    foul_comp = COMP_FOUL_PER_HOUR * since_wash
    foul_turb = TURB_FOUL_FULL * hours_run / C.FULL_HOURS
    foul_ic = IC_FOUL_FULL * hours_run / C.FULL_HOURS
    days = time_s / 86400.0
    hull = HULL_FOUL_PER_YEAR * days / 365.25

    steady_advance = pitch**0.8 / (1.0 + hull) ** (1.0 / 3.0)
    ship = first_order_lag(n_rel * steady_advance, TAU_SHIP_S, dt, starts)
    advance = ship / np.maximum(n_rel, 0.3)
    waves = ar1_noise(n_tot, 1.0, TAU_WAVES_S, dt, rng, starts) * (WAVE_LOAD[0] + WAVE_LOAD[1] * sea)
    sea_lag = first_order_lag(sea, TAU_SEA_S, dt, starts)
    p_prop = propeller_power(speed, pitch, advance) * (1.0 + sea_lag + waves)
    omega = speed * C.RPM_TO_RAD_S
    domega = np.empty(n_tot)
    for a, b in zip(starts, np.r_[starts[1:], n_tot]):
        domega[a:b] = np.gradient(omega[a:b], dt) if b - a > 1 else 0.0
    p_demand = np.clip(p_prop + SHAFT_INERTIA_KG_M2 * omega * domega, 0.005 * C.P_MCR_W, P_DEMAND_MAX * C.P_MCR_W)

    offsets = np.array([v.sea_offset_c for v in voyages])
    next_offsets = np.r_[offsets[1:], offsets[-1]]
    frac = local / np.maximum(np.array([v.n for v in voyages])[voyage], 1)
    diurnal = np.sin(2.0 * np.pi * days - 1.0)
    seawater_c = (SEAWATER_MEAN_C + SEAWATER_SEASONAL_C * np.sin(2.0 * np.pi * (day0 + days - 110.0) / 365.25)
                  + offsets[voyage] * (1.0 - frac) + next_offsets[voyage] * frac + SEAWATER_DIURNAL_C * diurnal)
    load_lag = first_order_lag(p_demand / C.P_MCR_W, TAU_ENGINE_ROOM_S, dt, starts)
    engine_room_c = seawater_c + ENGINE_ROOM_ABOVE_SEA_C + ENGINE_ROOM_LOAD_C * load_lag + 1.0 * diurnal
    p_amb = P_AMB_MEAN_PA + ar1_noise(n_tot, P_AMB_SD_PA, P_AMB_TAU_S, dt, rng, starts)

    return Profile(
        dt=dt, time_s=time_s, voyage=voyage, logged=logged, manoeuvre=manoeuvre, lever=lever,
        speed_ref_rpm=speed_ref, speed_rpm=speed, pitch=pitch, ship_speed=ship, power_demand_w=p_demand,
        seawater_k=seawater_c + C.KELVIN, engine_room_k=engine_room_c + C.KELVIN, p_amb_pa=p_amb,
        foul_comp=foul_comp, foul_turb=foul_turb, foul_ic=foul_ic, hull=hull, running_hours=hours_run,
    )
