"""The synthetic ``turboshaft`` dataset: twin-engine helicopter flights at 12 Hz.

``generate`` draws two engines (small scatter), a set of flights (manoeuvre profiles,
per-flight weather and weight), cuts each flight's recording into trajectories of a
few minutes separated by short unrecorded gaps, simulates every trajectory of every
flight in one batched closed loop (each starts trimmed 20 s before its first recorded
sample), adds independent sensor noise to each engine's record, and returns a
``Dataset`` whose segments are one engine's trajectory (``F012-E1-T03``) with a
published 60/20/20 split by whole flights.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np
import pandas as pd

from enginebench.datasets.dataset import SEGMENT, TIME, Dataset
from enginebench.datasets.schema import Column, Schema
from enginebench.datasets.turboshaft.closed_loop import LoopInputs, simulate_closed_loop
from enginebench.datasets.turboshaft.params import (
    P_REF, WF_REF, AirframeParams, EngineParams, FadecParams, RotorParams, draw_engines,
)
from enginebench.datasets.turboshaft.profile import FlightProfile, make_flight
from enginebench.errors import DataError

NAME = "turboshaft"
GENERATOR_VERSION = "1"
DT = 1.0 / 12.0
PREROLL_S = 20.0
"""Simulated seconds before each trajectory's first recorded sample (not recorded)."""
MIN_HOURS = 0.1
MIN_FLIGHTS = 5
MEAN_FLIGHT_H = 0.8
PIECE_S = (120.0, 360.0)
"""Trajectory lengths, seconds (uniform); a last piece shorter than MIN_PIECE_S joins the one before."""
MIN_PIECE_S = 60.0
GAP_S = (5.0, 40.0)

SCHEMA = Schema((
    Column("COL", "input", "%"),
    Column("NR", "input", "%"),
    Column("airspeed", "input", "kn"),
    Column("P0", "input", "kPa"),
    Column("T1", "input", "K"),
    Column("TRQ", "output", "%"),
    Column("WF", "output", "kg/h"),
    Column("NG", "internal", "%"),
    Column("NP", "internal", "%"),
    Column("flight", "group", "id"),
    Column("engine", "group", "id"),
))
"""Columns, roles and units: controls COL, NR and uncontrolled airspeed, P0, T1 are
inputs; TRQ (the cascade's final target) and WF (predicted from the controls) are
outputs; NG and NP are test-campaign internals. TRQ is in % of one engine's
maximum-continuous torque at 100 % NP."""

SENSOR_NOISE = {
    "COL": 0.1, "NR": 0.03, "airspeed": 0.5, "P0": 0.03, "T1": 0.15,
    "TRQ": 0.25, "WF": 0.6, "NG": 0.05, "NP": 0.03,
}
"""Standard deviation of the white sensor noise per column, in the column's unit."""


@dataclass(frozen=True)
class Simulation:
    """Noise-free result of the batched flight simulation (before recording).

    Trajectory ``p`` is flight ``piece_flight[p]``'s ``piece_index[p]``-th recorded piece,
    starting at profile sample ``piece_start[p]`` and lasting ``piece_length[p]`` samples;
    in ``inputs`` and ``outputs`` (time axis first) it occupies rows ``preroll`` to
    ``preroll + piece_length[p]`` of column ``p``. ``phase`` and ``phase_age`` (same
    shape as the inputs) say which manoeuvre (``profile.PHASES``) was flown and for how
    many seconds, to pick steady phases.
    """

    flights: tuple[FlightProfile, ...]
    engines: EngineParams
    piece_flight: np.ndarray
    piece_index: np.ndarray
    piece_start: np.ndarray
    piece_length: np.ndarray
    preroll: int
    inputs: LoopInputs
    outputs: dict[str, np.ndarray]
    phase: np.ndarray
    phase_age: np.ndarray


def _recorded_samples(hours: float, n_flights: int, rng: np.random.Generator) -> np.ndarray:
    """Recorded samples per flight: variable flights that add up to exactly ``hours``."""
    total = int(round(hours * 3600.0 / DT))
    share = 0.5 / n_flights + 0.5 * rng.dirichlet(np.full(n_flights, 6.0))
    counts = np.floor(share * total).astype(np.int64)
    counts[: total - counts.sum()] += 1
    return counts


def _cut(samples: int, rng: np.random.Generator) -> list[int]:
    """Trajectory lengths (samples) of one flight's recording."""
    lo, hi = (int(round(s / DT)) for s in PIECE_S)
    minimum = int(round(MIN_PIECE_S / DT))
    pieces: list[int] = []
    left = samples
    while left > 0:
        take = min(int(rng.integers(lo, hi + 1)), left)
        pieces.append(take)
        left -= take
    if len(pieces) > 1 and pieces[-1] < minimum:
        last = pieces.pop()
        pieces[-1] += last
    return pieces


def simulate_flights(
    hours: float,
    rng: np.random.Generator,
    progress: Callable[[float], None] | None = None,
    *,
    fadec: FadecParams | None = None,
    rotor: RotorParams | None = None,
    air: AirframeParams | None = None,
) -> Simulation:
    """Draw engines and flights totalling ``hours`` recorded per engine, and simulate them."""
    fadec, rotor, air = fadec or FadecParams(), rotor or RotorParams(), air or AirframeParams()
    rng_engines, rng_flights, rng_pieces = rng.spawn(3)
    engines = draw_engines(rng_engines, 2)
    n_flights = max(MIN_FLIGHTS, int(round(hours / MEAN_FLIGHT_H)))
    recorded = _recorded_samples(hours, n_flights, rng_pieces)
    preroll = int(round(PREROLL_S / DT))

    flights, pf, pi, ps, pl = [], [], [], [], []
    for f, rec in enumerate(recorded):
        lengths = _cut(int(rec), rng_pieces)
        gaps = rng_pieces.integers(int(GAP_S[0] / DT), int(GAP_S[1] / DT) + 1, size=len(lengths))
        gaps[0] = preroll + rng_pieces.integers(0, preroll + 1)  # recording starts on the ground
        starts = np.cumsum(gaps) + np.r_[0, np.cumsum(lengths)[:-1]]
        needed = int(starts[-1] + lengths[-1])
        prof = make_flight(rng_flights, f"F{f + 1:03d}", needed * DT + 1.0, DT, rotor, air, fadec)
        assert len(prof) >= needed, "flight profile shorter than its recording"
        flights.append(prof)
        pf += [f] * len(lengths)
        pi += list(range(len(lengths)))
        ps += list(starts)
        pl += list(lengths)
        if progress is not None:
            progress(0.1 * (f + 1) / n_flights)
    piece_flight, piece_index = np.array(pf), np.array(pi)
    piece_start, piece_length = np.array(ps, dtype=np.int64), np.array(pl, dtype=np.int64)

    # gather every trajectory's inputs into (T, batch) arrays (held constant past its end)
    offsets = np.r_[0, np.cumsum([len(p) for p in flights])]
    flight_len = np.diff(offsets)
    T = preroll + int(piece_length.max())
    local = (piece_start - preroll)[None, :] + np.arange(T)[:, None]
    local = np.minimum(local, (flight_len[piece_flight] - 1)[None, :])
    idx = offsets[piece_flight][None, :] + local

    def gather(name: str) -> np.ndarray:
        return np.concatenate([getattr(p, name) for p in flights])[idx]

    inputs = LoopInputs(
        col=gather("col"), airspeed=gather("airspeed"), p0=gather("p0"), t1=gather("t1"),
        rho=gather("rho"), nr_ref=gather("nr_ref"), load_factor=gather("load_factor"),
    )
    sim_progress = None if progress is None else (lambda x: progress(0.1 + 0.8 * x))
    outputs = simulate_closed_loop(inputs, engines, fadec, rotor, dt=DT, progress=sim_progress)
    return Simulation(
        flights=tuple(flights), engines=engines, piece_flight=piece_flight, piece_index=piece_index,
        piece_start=piece_start, piece_length=piece_length, preroll=preroll, inputs=inputs,
        outputs=outputs, phase=gather("phase"), phase_age=gather("phase_age"),
    )


def published_split(flight_ids: list[str], rng: np.random.Generator) -> dict[str, list[str]]:
    """About 60/20/20 of the flights (whole flights) for train/validation/test, at random."""
    n = len(flight_ids)
    order = [flight_ids[i] for i in rng.permutation(n)]
    n_val = max(1, int(round(0.2 * n)))
    n_test = max(1, int(round(0.2 * n)))
    n_train = n - n_val - n_test
    if n_train < 1:
        raise DataError(f"cannot split {n} flight(s) into train/validation/test; need at least 3")
    return {
        "train": sorted(order[:n_train]),
        "validation": sorted(order[n_train:n_train + n_val]),
        "test": sorted(order[n_train + n_val:]),
    }


def record(sim: Simulation, rng: np.random.Generator) -> pd.DataFrame:
    """The long frame of recorded signals: one segment per (flight, engine, trajectory), sensor noise added.

    Each engine's record has its own sensors, so shared signals (COL, NR, airspeed,
    P0, T1) carry independent noise in the two engines' segments.
    """
    n_engines = sim.engines.n_engines
    names = [p.flight for p in sim.flights]
    width = max(2, len(str(int(sim.piece_index.max()) + 1)))
    seg_ids, seg_e, seg_p = [], [], []
    for f in range(len(sim.flights)):
        pieces = np.flatnonzero(sim.piece_flight == f)
        for e in range(n_engines):
            for p in pieces:
                seg_ids.append(f"{names[f]}-E{e + 1}-T{sim.piece_index[p] + 1:0{width}d}")
                seg_e.append(e)
                seg_p.append(p)
    seg_e_arr, seg_p_arr = np.array(seg_e), np.array(seg_p)
    lengths = sim.piece_length[seg_p_arr]
    row_e = np.repeat(seg_e_arr, lengths)
    row_p = np.repeat(seg_p_arr, lengths)
    within = np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    row_t = sim.preroll + within

    inp, out = sim.inputs, sim.outputs
    clean = {
        "COL": 100.0 * inp.col[row_t, row_p],
        "NR": out["NR"][row_t, row_p],
        "airspeed": inp.airspeed[row_t, row_p],
        "P0": inp.p0[row_t, row_p],
        "T1": inp.t1[row_t, row_p],
        "TRQ": out["TRQ"][row_t, row_p, row_e],
        "WF": out["WF"][row_t, row_p, row_e],
        "NG": out["NG"][row_t, row_p, row_e],
        "NP": out["NP"][row_t, row_p, row_e],
    }
    n = len(row_t)
    frame = {
        SEGMENT: np.repeat(np.array(seg_ids, dtype=object), lengths),
        TIME: (sim.piece_start[row_p] + within) * DT,
    }
    for name, values in clean.items():
        frame[name] = values + SENSOR_NOISE[name] * rng.standard_normal(n)
    frame["airspeed"] = np.maximum(frame["airspeed"], 0.0)
    frame["flight"] = np.array(names, dtype=object)[sim.piece_flight[row_p]]
    frame["engine"] = np.array([f"E{e + 1}" for e in range(n_engines)], dtype=object)[row_e]
    return pd.DataFrame(frame)


def generate(hours: float = 13.0, seed: int = 0, progress: Callable[[float], None] | None = None) -> Dataset:
    """The synthetic twin-engine turboshaft dataset: ``hours`` of flight per engine at 12 Hz.

    Deterministic given ``seed``. ``progress``, if given, is called with the fraction
    done (0..1). See the module docstring for what is simulated.
    """
    if not isinstance(hours, (int, float)) or not np.isfinite(hours) or hours < MIN_HOURS:
        raise DataError(
            f"turboshaft generator: hours={hours!r} is not a usable recording length; it makes at least "
            f"{MIN_FLIGHTS} flights of at least a minute each, so use hours >= {MIN_HOURS} (default 13)"
        )
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise DataError(f"turboshaft generator: seed must be a non-negative integer, got {seed!r}")
    rng_sim, rng_noise, rng_split = np.random.default_rng(int(seed)).spawn(3)
    sim = simulate_flights(float(hours), rng_sim, progress)
    frame = record(sim, rng_noise)
    flights = [p.flight for p in sim.flights]
    by_flight = published_split(flights, rng_split)
    seg_flight = frame.drop_duplicates(SEGMENT)[[SEGMENT, "flight"]]
    split = {
        side: seg_flight.loc[seg_flight["flight"].isin(ids), SEGMENT].tolist() for side, ids in by_flight.items()
    }
    meta = {
        "provenance": f"synthetic: enginebench turboshaft generator v{GENERATOR_VERSION}, seed {int(seed)}",
        "license": "CC0-1.0 (synthetic data, no third-party content)",
        "synthetic": True,
        "description": (
            "Twin-engine helicopter flights at 12 Hz: manoeuvre profiles, ISA atmosphere with a per-flight "
            "temperature offset, FADEC fuel control (rotor-speed PID + collective lead-lag, gains scheduled on "
            "delta*sqrt(theta), min/max and rate limits), rotor-speed dynamics, gas-generator and torque "
            "dynamics with scheduled time constants and a slow heat-soak mode, engine-to-engine scatter, "
            "sensor noise. One segment = one engine's trajectory within a flight."
        ),
        "generator": {"name": "enginebench.datasets.turboshaft", "version": GENERATOR_VERSION,
                      "seed": int(seed), "hours": float(hours)},
        "published_split": split,
        "published_split_flights": by_flight,
        "split_by": "flight",
        "reference_values": {"TRQ_100pct_kW_at_100pct_NP": P_REF, "WF_at_max_continuous_kg_h": WF_REF},
        "engine_parameters": {f"E{e + 1}": {k: float(np.asarray(v)[e]) for k, v in asdict(sim.engines).items()}
                              for e in range(sim.engines.n_engines)},
    }
    ds = Dataset(name=NAME, frame=frame, schema=SCHEMA, dt=DT, meta=meta)
    if progress is not None:
        progress(1.0)
    return ds
