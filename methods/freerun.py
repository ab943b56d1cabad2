"""What every model with output feedback needs in simulation mode: signals, the init window, the envelope.

Shared by ``arx``, ``narx`` and the peer adapters so that all of them read the data the
same way:

- Training: each training segment is one contiguous trajectory, inputs ``U[rows]`` and
  measured outputs ``y`` (whole segments in simulation mode); lags never cross a
  segment boundary.
- Prediction: a segment's measured outputs are known only inside its state
  initialisation window, raw rows ``0 .. N-1`` (``y_init``); without a window (N = 0)
  the window is the single measured output ``y0`` at raw row 0. After the window the
  model runs free. Lags that reach before raw row 0 take the earliest value (edge
  padding), for inputs and outputs alike.
- Divergence: a free run that turns non-finite or leaves the envelope
  [min - e * span, max + e * span] of the training outputs (span = max - min, e the
  ``envelope`` option, as ``sindy``) is held at its last in-envelope value from there on
  and its segment is flagged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

import numpy as np

from enginebench.declare import Field, Invalid, is_number, positive
from enginebench.errors import MethodError
from enginebench.samples import Samples, SegmentSamples

if TYPE_CHECKING:
    from enginebench.method import TrainingShape


@dataclass(frozen=True)
class Trajectory:
    """One training segment as a contiguous trajectory: inputs (n, c) and measured outputs (n, k)."""

    id: str
    U: np.ndarray
    Y: np.ndarray


def _first_bad(values: np.ndarray) -> tuple[int, int]:
    row, col = np.argwhere(~np.isfinite(values))[0]
    return int(row), int(col)


def training_trajectories(who: str, train: Samples) -> list[Trajectory]:
    """The training segments as trajectories; MethodError for missing targets, gaps or nan/inf."""
    if not train.segments:
        raise MethodError(f"method {who!r}: the training samples are empty; give at least one training segment")
    out = []
    for s in train.segments:
        if s.y is None:
            raise MethodError(f"method {who!r}: training segment {s.id!r} carries no targets")
        rows = np.asarray(s.rows)
        if len(rows) > 1 and not np.all(np.diff(rows) == 1):
            raise MethodError(f"method {who!r}: training segment {s.id!r} is not contiguous (rows subsampled); "
                              "models with output lags need whole segments (simulation mode)")
        U = np.asarray(s.U, dtype=np.float64)[rows]
        for what, arr, names in (("input", U, train.input_names), ("target", s.y, train.target_names)):
            if not np.isfinite(arr).all():
                row, col = _first_bad(arr)
                raise MethodError(f"method {who!r}: training segment {s.id!r} has nan/inf in {what} "
                                  f"{names[col]!r} at row {row}; clean or drop those rows")
        out.append(Trajectory(s.id, U, np.asarray(s.y, dtype=np.float64)))
    return out


def check_prediction_inputs(who: str, data: Samples, n_inputs: int) -> None:
    """MethodError when the data's inputs differ in number from the fitted model's or hold nan/inf."""
    if data.mode != "simulation":
        raise MethodError(f"method {who!r} simulates with output feedback and needs mode 'simulation', got {data.mode!r}")
    for s in data.segments:
        for what, arr in (("feature", s.X), ("input", s.U)):
            arr = np.asarray(arr)
            if arr.ndim != 2 or arr.shape[1] != n_inputs:
                raise MethodError(f"method {who!r}: segment {s.id!r} has {arr.shape[-1] if arr.ndim else 0} {what} "
                                  f"columns but the model was fitted on {n_inputs} inputs; predict with the same inputs")
            if not np.isfinite(arr).all():
                row, col = _first_bad(arr)
                raise MethodError(f"method {who!r}: segment {s.id!r} has nan/inf in {what} column {col} at row {row}; "
                                  "clean or drop it")


def init_window(who: str, s: SegmentSamples, n_targets: int) -> np.ndarray:
    """The measured outputs a free run may use, (N, k): ``y_init``, or ``y0`` alone when the window is empty."""
    window = None if s.y_init is None else np.asarray(s.y_init, dtype=np.float64).reshape(-1, n_targets)
    if window is None or len(window) == 0:
        if s.y0 is None:
            raise MethodError(f"method {who!r}: segment {s.id!r} has no measured initial output (y0 or y_init); "
                              "simulation needs at least the output at its first row")
        window = np.asarray(s.y0, dtype=np.float64).reshape(1, n_targets)
    if not np.isfinite(window).all():
        row, _ = _first_bad(window)
        raise MethodError(f"method {who!r}: segment {s.id!r} has a nan/inf measured output in its init window "
                          f"(row {row}); clean the record or move the window")
    return window


def padded_past(values: np.ndarray, lags: int) -> np.ndarray:
    """``values`` (n, ...) with ``lags`` copies of its first row in front: row i of the result is time i - lags."""
    if lags <= 0:
        return values
    return np.concatenate([np.repeat(values[:1], lags, axis=0), values])


@dataclass(frozen=True)
class Envelope:
    """Bounds of a free run per target: leaving them (or going non-finite) is divergence."""

    lower: np.ndarray
    upper: np.ndarray

    @classmethod
    def around(cls, Y: np.ndarray, factor: float) -> "Envelope":
        """[min - factor * span, max + factor * span] of the training outputs Y (n, k); span 0 counts as 1."""
        lo, hi = Y.min(axis=0), Y.max(axis=0)
        span = np.where(hi > lo, hi - lo, 1.0)
        return cls(lo - factor * span, hi + factor * span)

    def clip_run(self, traj: np.ndarray, start: int) -> tuple[np.ndarray, bool]:
        """Hold ``traj`` (n, k) at its last good row from the first row >= ``start`` outside the envelope.

        Returns the (possibly modified) trajectory and whether it diverged. Rows before
        ``start`` are measured (the init window) and never checked.
        """
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(traj[start:]).all(axis=1) | (traj[start:] < self.lower).any(axis=1) \
                | (traj[start:] > self.upper).any(axis=1)
        if not bad.any():
            return traj, False
        first = start + int(np.argmax(bad))
        traj = traj.copy()
        traj[first:] = traj[first - 1] if first > 0 else np.clip(np.nan_to_num(traj[0]), self.lower, self.upper)
        return traj, True


def as_orders(value: object) -> list[int] | None:
    """An order option as sorted distinct whole numbers (None stays None: derived from the data)."""
    if value is None:
        return None
    values = list(value) if isinstance(value, (list, tuple, np.ndarray)) else [value]
    return sorted({int(v) for v in values})


class GivenOrders:
    """Mixin of the ARX-type methods: their ``na``, ``nb``, ``nk`` options as sorted lists (None: derived)."""

    options: dict

    @property
    def given_orders(self) -> dict[str, list[int] | None]:
        return {key: as_orders(self.options[key]) for key in ("na", "nb", "nk")}

    def check_data(self, shape: "TrainingShape") -> None:
        """A given ``na``, ``nb`` or ``nk`` the training records cannot carry is refused before the first job: one
        whose lags leave no more rows (samples with that many earlier ones inside their record) than the model has
        coefficients at least (the lags' own plus a constant), so that every fit of it would fail."""
        top = carried_lags(shape)
        for key, values in self.given_orders.items():
            bad = [v for v in values or [] if v > top]
            if not bad:
                continue
            v = bad[-1]
            asks = f"delays the inputs by {v} samples" if key == "nk" else f"asks for {v} lags"
            todo = (f"use {key} of at most {top}, or longer records" if top else
                    "no lag fits these records: use longer ones")
            raise MethodError(
                f"method {getattr(self, 'name', '?')!r}: option {key} = {self.options[key]!r} {asks}, but the "
                f"{shape.describe()} have {shape.rows_after(v)} samples with {v} earlier ones in their record, fewer "
                f"than the {v + 1} coefficients such a model has at least; {todo}"
                + ("" if key == "nk" else f" (or leave {key} out to derive the grid from the data)")
            )

    def order_space(self, data: Samples, cap: int, base: Sequence[int], tied: str) -> dict[str, np.ndarray]:
        """The lag part of the search space: ``tied`` (na = nb) on the grid the training data carry
        (``derived_orders`` up to ``cap`` from ``base``) unless na or nb is given; else na and nb,
        each as given or on that grid."""
        given = self.given_orders
        sizes = [len(s) for s in data.segments] or [0]
        derived = derived_orders(min(sizes), sum(sizes), len(data.input_names), cap, base)
        if given["na"] is None and given["nb"] is None:
            return {tied: np.array(derived)}
        return {key: np.array(given[key] if given[key] is not None else derived) for key in ("na", "nb")}

    def order_bounds(self, data: Samples, cap: int, tied: str) -> dict[str, tuple[float | None, float | None]]:
        """Hard bounds of the lag orders for model selection's extension: 1 to the most lags the training data
        carry (``carried_order``) within ``cap``, for ``tied`` and for na and nb."""
        sizes = [len(s) for s in data.segments] or [0]
        top = max(carried_order(min(sizes), sum(sizes), len(data.input_names), cap), 1)
        return {key: (1.0, float(top)) for key in (tied, "na", "nb")}


def orders(name: str, default: object, meaning: str, low: int = 0, high: int | None = None, why: str = "",
           message: str = "", **kw: object) -> Field:
    """An order option (samples): None (derived from the data), one whole number in [low, high] or a list of them.

    ``message`` (an ``Invalid`` template) replaces every refusal; ``why`` explains the lower bound.
    """

    def check(value: object) -> object:
        if value is None:
            return None
        values = list(value) if isinstance(value, (list, tuple, np.ndarray)) else [value]
        if not values or not all(is_number(v) and float(v).is_integer() and v >= 0 for v in values):
            raise Invalid(message or "{name}={value} must be a whole number of samples >= 0 or a list of them (or "
                          "left out to derive the grid from the data)")
        if min(values) < low or (high is not None and max(values) > high):
            raise Invalid(message or "{name}={value} must be >= " + str(low) + (f" ({why})" if why else ""))
        return value

    label = f"int in [{low}, {high}]" if high is not None else f"int >= {low}"
    options = {"unit": "samples", "type_label": f"{label} | list[int] | None", **kw}
    return Field(name, default, meaning, kind="any", check=check, **options)  # type: ignore[arg-type]


ENVELOPE = positive("envelope", 10.0, "divergence: a simulated output leaving [min - e span, max + e span] of the "
                    "training outputs is held there and the segment counted as diverged")
"""The ``envelope`` option of the free-run methods."""


def carried_lags(shape: "TrainingShape") -> int:
    """The most lags L whose regression rows (samples with L earlier ones in their record) outnumber them (0: none)."""
    low, high = 0, shape.longest  # rows_after(L) - L falls as L grows: bisect for the last L where it is > 0
    while low < high:
        mid = (low + high + 1) // 2
        if shape.rows_after(mid) > mid:
            low = mid
        else:
            high = mid - 1
    return low


def carried_order(n_shortest: int, n_rows: int, n_inputs: int, cap: int) -> int:
    """The most lags (samples) the training data carry under ``derived_orders``' rules (0 when none)."""
    return int(max(0, min(cap, n_shortest // 4, (n_rows / 10 - 1) // (1 + n_inputs))))


def derived_orders(n_shortest: int, n_rows: int, n_inputs: int, cap: int, base: Sequence[int] = (1, 2, 4, 8, 16)
                   ) -> list[int]:
    """Lag orders (samples) from ``base`` that the training data can carry.

    An order o is kept when o <= cap, o <= a quarter of the shortest training segment
    (most of each segment remains usable as regression rows) and the regression with o
    output lags and o lags of each input has at most a tenth as many parameters as there
    are training rows. The smallest order is always kept.
    """
    top = carried_order(n_shortest, n_rows, n_inputs, cap)
    keep = [o for o in base if o <= top]
    return keep or [min(base)]
