"""Cascades (turboshaft-moe): an upstream model of an intermediate signal feeds a downstream model of the target.

The turboshaft torque TRQ depends on the fuel flow WF, which is measured only in a test
campaign (role ``internal``: in the training samples' ``Z``, never at prediction). A
cascade fits an *upstream* model of WF on the run-time inputs, then a *downstream*
model of TRQ whose inputs are the run-time inputs plus the intermediate column:

- ``source = "model"``: the downstream is fed the upstream's prediction of WF, during
  training (``train_on = "model"``, the paper's choice: the downstream learns to live with
  the upstream's errors) and at prediction. This is what runs in flight: MoE-NFIR,
  SINDy-NFIR (upstream NFIR) and MoE-MoE (upstream MoE), named downstream-upstream as in
  the turboshaft-moe paper's Table 3.
- ``source = "true"``: the measured intermediate is fed at prediction too. It is not
  available at run time, so this is an *ideal* baseline, and it needs the measured WF at
  prediction: the experiment must give WF the role ``input`` (``roles = { WF = "input" }``).
  Predictions only ever see run-time inputs (the runner strips ``Z``), so an ideal model
  cannot be had in an experiment where WF is ``internal``; the ideal classes below say so
  in their error and carry ``[ideal]`` in their name so that no table shows them unlabelled.

A simulating upstream (MoE, SINDy) needs the intermediate's initial value, which is not
measured at run time. It is estimated by a ridge regression of the intermediate on the
run-time inputs and the target at the same instant, fitted on the training rows and
evaluated at the first row (inputs and the measured initial target y0 are what every
simulation starts from). The same estimate is used in training and at prediction.

Surrogates (option ``surrogates``, e.g. ``["NG"]``): internal signals that the paper
reconstructs by NFIR from the run-time inputs and uses as schedulers. Each is fitted first
(NFIR on the run-time inputs, target from ``Z``) and its reconstruction is appended as an
input column that the upstream and the downstream models both see.

Hyperparameters: the cascade's search space is the downstream's (with ``downstream_params``
fixed), searched by the experiment's model selection. The upstream is tuned inside ``fit``
on a holdout of the training trajectories (the last ``upstream_holdout`` fraction, scored
by segment-averaged MAE) over its own search space with ``upstream_params`` fixed; when
every upstream hyperparameter is fixed there is no inner search.

The parts a cascade is built from (component classes, the samples each component sees,
the initial-value estimate, the holdout search, the fitted records) are
``cascade_components.py``.
"""

from __future__ import annotations

from typing import Any, ClassVar, Iterator, Sequence

import numpy as np

from enginebench.declare import Declaration, Invalid, anything, choice, number, table, text
from enginebench.errors import MethodError
from enginebench.method import Method, Params, SearchSpace, SegmentPredictions, grid_points
from enginebench.methods.cascade_components import (
    CascadeFitted, Initialiser, UpstreamFitted, component_class, holdout_search, initial_features, intermediate_values, target_samples, upstream_signals, with_inputs,
)
from enginebench.samples import Samples

__all__ = [
    "OPTIONS", "SOURCES", "TRAIN_ON", "Cascade", "MoEIdeal", "MoEMoE", "MoENFIR", "SINDyIdeal", "SINDyNFIR"
]

SOURCES = ("model", "true")
TRAIN_ON = ("model", "true")


def _names(value: Any) -> Any:
    """A column name or a list of distinct names."""
    names = [value] if isinstance(value, str) else value
    if not isinstance(names, (list, tuple)) or not names or not all(isinstance(n, str) and n for n in names) \
            or len(set(names)) != len(names):
        raise Invalid("{name}={value} must be a column name or a list of distinct column names")
    return value


def _distinct(value: Any) -> Any:
    if isinstance(value, str) or not isinstance(value, (list, tuple)) \
            or not all(isinstance(n, str) and n for n in value) or len(set(value)) != len(value):
        raise Invalid("{name}={value} must be a list of distinct column names, none of them an intermediate")
    return value


OPTIONS = Declaration(
    text("upstream", "nfir", "method of the intermediate(s): nfir, moe, sindy or any registered simulating method"),
    text("downstream", "moe", "method of the target: moe, sindy, nfir or any registered simulating method"),
    anything("intermediate", "WF", "intermediate column, or a list of them (one upstream model each)", check=_names,
             type_label="str | list[str]"),
    choice("source", "model", "fed to the downstream: the upstream's simulated intermediate (model) or the "
           "measured one (true: an ideal baseline, needs role input)", SOURCES),
    choice("train_on", "model", "what the downstream is trained on when source = model", TRAIN_ON),
    table("upstream_options", {}, "options of the upstream method"),
    table("downstream_options", {}, "options of the downstream method"),
    table("upstream_params", {}, "fixed upstream hyperparameters; the rest are tuned on the holdout"),
    table("downstream_params", {}, "fixed downstream hyperparameters (removed from the search)"),
    number("upstream_holdout", 0.25, "fraction of training trajectories that tune the upstream", low=0, high=1,
           low_open=True, high_open=True, message="{name} must lie strictly between 0 and 1, got {value}"),
    choice("intermediate_sign", "+", "moe downstream: sign of the intermediate's coefficient", ("+", "-", "free")),
    anything("surrogates", [], "internal columns (e.g. NG) reconstructed by NFIR and fed to upstream and "
             "downstream", check=_distinct, type_label="list[str]"),
    table("surrogate_options", {}, "options of the surrogates' NFIR"),
    table("surrogate_params", {}, "fixed NFIR hyperparameters of the surrogates; the rest are tuned on the holdout"),
)
"""The cascade's options; each preset class (``moe-nfir``...) changes some defaults."""


class Cascade(Method):
    """Upstream model of an intermediate signal -> downstream model of the target (simulation mode)."""

    name = "cascade"
    family = "hybrid"
    modes = frozenset({"simulation"})
    summary = ("cascade: an upstream model of an intermediate (e.g. WF) feeds a downstream model of the target "
               "(turboshaft-moe)")
    preset: ClassVar[dict[str, Any]] = {}

    declared_options = OPTIONS

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls.declared_options = OPTIONS.with_defaults(**cls.preset)

    @classmethod
    def grid_edges(cls) -> dict[str, str]:
        """The default downstream's (the cascade searches the downstream's space)."""
        return component_class(cls.default_options()["downstream"]).grid_edges()

    def __init__(self, **options: Any) -> None:
        super().__init__(**options)
        o = self.options
        self.intermediates = tuple([o["intermediate"]] if isinstance(o["intermediate"], str) else o["intermediate"])
        if set(o["surrogates"]) & set(self.intermediates):
            raise MethodError(f"method {self.name!r}: option surrogates={o['surrogates']!r} must be a list of distinct "
                              "column names, none of them an intermediate")
        self.surrogates = tuple(o["surrogates"])
        self.up_cls = component_class(o["upstream"]) if o["source"] == "model" else None
        self.down_cls = component_class(o["downstream"])
        for role, cls in (("upstream", self.up_cls), ("downstream", self.down_cls)):
            if cls is not None and "simulation" not in cls.modes:
                raise MethodError(f"method {self.name!r}: {role} method {cls.name!r} has no simulation mode")
        if self.up_cls is not None:
            self.up_cls(**o["upstream_options"])  # fail early on bad options
        if self.surrogates:
            component_class("nfir")(**o["surrogate_options"])
        self._downstream(("y",), "WF")  # likewise

    # -- components -----------------------------------------------------------------------
    def _downstream(self, targets: Sequence[str], intermediate: str) -> Method:
        """The downstream method; one that declares a ``signs`` option (MoE) gets the turboshaft-moe paper's signs (own state -,
        intermediate +) unless told otherwise."""
        opts = dict(self.options["downstream_options"])
        declares_signs = "signs" in self.down_cls.default_options()
        if declares_signs and "signs" not in opts and self.options["intermediate_sign"] != "free":
            opts["signs"] = {**{t: "-" for t in targets}, **{n: self.options["intermediate_sign"] for n in self.intermediates}}
        return self.down_cls(**opts)

    def _down_inputs(self, data: Samples) -> tuple[str, ...]:
        """Downstream inputs: run-time inputs other than the intermediates, then the intermediates."""
        return tuple(c for c in data.input_names if c not in self.intermediates) + self.intermediates

    def _check(self, data: Samples) -> None:
        self.check_mode(data.mode)
        if self.options["source"] == "true":
            absent = [n for n in self.intermediates if n not in data.input_names]
            if absent:
                role = "internal" if absent[0] in data.internal_names else "not a run-time input"
                raise MethodError(
                    f"method {self.name!r} feeds the measured {absent[0]} at prediction (ideal baseline, not available "
                    f"at run time), so {absent[0]} must be a run-time input of the experiment; here it is {role}: "
                    f"set roles = {{ {absent[0]} = \"input\" }} in an experiment of its own"
                )
        clash = [n for n in self.intermediates if n in data.target_names]
        if clash:
            raise MethodError(f"method {self.name!r}: the intermediate {clash[0]!r} is also the target; "
                              "cascade an intermediate into a different target")

    def check_columns(self, inputs: Sequence[str], internals: Sequence[str], targets: Sequence[str]) -> None:
        """Options ``intermediate`` and ``surrogates`` name internal columns or run-time inputs of the data (with
        ``source = "true"`` an intermediate must be a run-time input), never a target; checked before the first job."""
        for key, names in (("intermediate", self.intermediates), ("surrogates", self.surrogates)):
            for n in names:
                if n in targets:
                    raise MethodError(f"method {self.name!r}: option {key} names {n!r}, which is also the target; "
                                      f"cascade through a column other than the target")
                if n not in inputs and n not in internals:
                    raise MethodError(
                        f"method {self.name!r}: option {key} names {n!r}, which is not a column of the data (run-time "
                        f"inputs: {', '.join(inputs) or 'none'}; internal columns: {', '.join(internals) or 'none'}); "
                        f"name one of them, or give {n} the role 'internal' (roles = {{ {n} = \"internal\" }})")
        if self.options["source"] == "true":
            absent = [n for n in self.intermediates if n not in inputs]
            if absent:
                raise MethodError(
                    f"method {self.name!r} feeds the measured {absent[0]} at prediction (ideal baseline, not available "
                    f"at run time), so {absent[0]} must be a run-time input of the experiment; here it is internal: "
                    f"set roles = {{ {absent[0]} = \"input\" }} in an experiment of its own")

    def _fit_upstream(self, train: Samples, name: str, rng: np.random.Generator, surrogate: bool = False) -> UpstreamFitted:
        """Fit the model of one intermediate (or, with ``surrogate``, the NFIR of one surrogate) on ``train``."""
        if surrogate:
            cls, options, fixed = component_class("nfir"), "surrogate_options", "surrogate_params"
            exclude = set(self.intermediates) | set(self.surrogates)
        else:
            cls, options, fixed, exclude = self.up_cls, "upstream_options", "upstream_params", set(self.intermediates)
        inputs = tuple(c for c in train.input_names if c not in exclude)
        if not inputs:
            raise MethodError(f"method {self.name!r}: no run-time input left to predict {name!r} from")
        truth = intermediate_values(train, name)
        init = Initialiser.fit(
            np.hstack([np.concatenate([s.U[s.rows][:, [train.input_names.index(c) for c in inputs]] for s in train.segments]),
                       train.y]),
            np.concatenate([z[s.rows] for z, s in zip(truth, train.segments)]),
        )
        z0 = init(initial_features(train, inputs, [s.y0 if s.y0 is not None else s.y[0] for s in train.segments]))
        up_train = target_samples(train, name, inputs, truth, list(z0))
        method = cls(**self.options[options])
        space = dict(method.search_space(up_train))
        space.update({k: np.array([v]) for k, v in self.options[fixed].items()})
        params, search = holdout_search(method, up_train, grid_points(space), self.options["upstream_holdout"], rng)
        fitted = method.fit(up_train, params, rng)
        return UpstreamFitted(name=name, method=method, fitted=fitted, inputs=inputs,
                              params={k: _plain(v) for k, v in params.items()}, search=search, initialiser=init)

    def _down_samples(self, data: Samples, signals: list[list[np.ndarray]]) -> Samples:
        """``data`` with the intermediates (``signals[i][segment]``) as the last input columns."""
        names = self._down_inputs(data)
        keep = [data.input_names.index(c) for c in names[: len(names) - len(self.intermediates)]]
        U = [np.column_stack([s.U[:, keep]] + [sig[k] for sig in signals]) for k, s in enumerate(data.segments)]
        return with_inputs(data, names, U)

    def _with_surrogates(self, data: Samples, surs: list[UpstreamFitted]) -> Samples:
        """``data`` with each surrogate's NFIR reconstruction appended as a run-time input column."""
        if not surs:
            return data
        signals, _ = upstream_signals(surs, data, self.name)
        U = [np.column_stack([s.U] + [sig[k] for sig in signals]) for k, s in enumerate(data.segments)]
        return with_inputs(data, data.input_names + tuple(u.name for u in surs), U)

    def _prepare_train(self, train: Samples, rng: np.random.Generator) -> tuple[list[UpstreamFitted], Samples]:
        """(surrogate and upstream models, downstream training samples)."""
        self._check(train)
        surs = [self._fit_upstream(train, n, rng, surrogate=True) for n in self.surrogates]
        train = self._with_surrogates(train, surs)
        if self.options["source"] == "true":
            return surs, self._down_samples(train, [intermediate_values(train, n) for n in self.intermediates])
        ups = [self._fit_upstream(train, n, rng) for n in self.intermediates]
        if self.options["train_on"] == "true":
            signals = [intermediate_values(train, n) for n in self.intermediates]
        else:
            signals, _ = upstream_signals(ups, train, self.name)
        return surs + ups, self._down_samples(train, signals)

    def _prepare_eval(self, models: list[UpstreamFitted], data: Samples) -> tuple[Samples, np.ndarray]:
        self._check(data)
        surs, ups = models[: len(self.surrogates)], models[len(self.surrogates):]
        data = self._with_surrogates(data, surs)
        if self.options["source"] == "true":
            return self._down_samples(data, [intermediate_values(data, n) for n in self.intermediates]), \
                np.zeros(len(data.segments), dtype=bool)
        signals, diverged = upstream_signals(ups, data, self.name)
        return self._down_samples(data, signals), diverged

    # -- Method -----------------------------------------------------------------------------
    def search_space(self, data: Samples) -> SearchSpace:
        space = dict(self._downstream(data.target_names, self.intermediates[0]).search_space(data))
        for k, v in self.options["downstream_params"].items():
            space[k] = np.array([v])
        return space

    def fit(self, train: Samples, params: Params, rng: np.random.Generator) -> CascadeFitted:
        ups, down_train = self._prepare_train(train, rng)
        down = self._downstream(train.target_names, self.intermediates[0])
        fitted = down.fit(down_train, {**dict(params)}, rng)
        return CascadeFitted(upstreams=ups, downstream=down, fitted=fitted, down_inputs=down_train.input_names,
                             source=self.options["source"], intermediates=self.intermediates)

    def predict(self, fitted: CascadeFitted, data: Samples) -> SegmentPredictions:
        # the models of one fit_grid share their upstreams: their signals on ``data`` are computed once
        if fitted.shared.get("data") is data:
            down_data, up_diverged = fitted.shared["prepared"]
        else:
            down_data, up_diverged = self._prepare_eval(fitted.upstreams, data)
            fitted.shared.update(data=data, prepared=(down_data, up_diverged))
        preds = fitted.downstream.predict(fitted.fitted, down_data)
        diverged = np.asarray(getattr(preds, "diverged", np.zeros(len(preds), bool))) | up_diverged
        return SegmentPredictions(list(preds), diverged)

    def keeps_grid_models(self) -> bool:
        """As the downstream method: the cascade's grid is the downstream's."""
        return self.down_cls(**dict(self.options["downstream_options"])).keeps_grid_models()

    def fit_grid(self, train: Samples, grid: Sequence[Params], rng: np.random.Generator
                 ) -> Iterator[tuple[int, CascadeFitted]]:
        """The upstream is fitted once; the downstream's own ``fit_grid`` covers the grid (MoE: one
        training run per point apart from epochs)."""
        ups, down_train = self._prepare_train(train, rng)
        down = self._downstream(train.target_names, self.intermediates[0])
        shared: dict[str, Any] = {}
        for i, fitted in down.fit_grid(down_train, grid, rng):
            yield i, CascadeFitted(upstreams=ups, downstream=down, fitted=fitted, down_inputs=down_train.input_names,
                                   source=self.options["source"], intermediates=self.intermediates, shared=shared)

    def predict_grid(
        self, train: Samples, data: Samples, grid: Sequence[Params], rng: np.random.Generator
    ) -> np.ndarray:
        """The upstream is fitted once; the downstream's own ``predict_grid`` covers the grid (or, where the
        downstream predicts through ``fit_grid``, this cascade's ``fit_grid``)."""
        if self.keeps_grid_models():
            return Method.predict_grid(self, train, data, grid, rng)
        ups, down_train = self._prepare_train(train, rng)
        down_data, _ = self._prepare_eval(ups, data)
        down = self._downstream(train.target_names, self.intermediates[0])
        return down.predict_grid(down_train, down_data, grid, rng)

    def describe(self, fitted: CascadeFitted) -> dict[str, Any]:
        out: dict[str, Any] = {
            "surrogates": [
                {"method": "nfir", "signal": u.name, "inputs": list(u.inputs), "params": u.params, "search": u.search}
                for u in fitted.upstreams[: len(self.surrogates)]
            ],
            "source": fitted.source,
            "available_at_run_time": fitted.source == "model",
            "intermediates": list(fitted.intermediates),
            "downstream": {"method": fitted.downstream.name, "inputs": list(fitted.down_inputs),
                           **fitted.downstream.describe(fitted.fitted)},
        }
        if fitted.source == "true":
            out["note"] = ("ideal baseline: the measured " + ", ".join(fitted.intermediates)
                           + " is fed at prediction; not available at run time")
        else:
            out["train_on"] = self.options["train_on"]
            out["upstream"] = [
                {"method": u.method.name, "intermediate": u.name, "inputs": list(u.inputs), "params": u.params,
                 "search": u.search, **u.method.describe(u.fitted)}
                for u in fitted.upstreams[len(self.surrogates):]
            ]
        return out

    # -- for plots ----------------------------------------------------------------------------
    def intermediate_predictions(self, fitted: CascadeFitted, data: Samples) -> dict[str, list[np.ndarray]]:
        """Each intermediate as fed to the downstream, per segment over its evaluated rows."""
        down_data, _ = self._prepare_eval(fitted.upstreams, data)
        out = {}
        for n in self.surrogates + fitted.intermediates:
            j = down_data.input_names.index(n)
            out[n] = [s.U[s.rows, j] for s in down_data.segments]
        return out

    def downstream_view(self, fitted: CascadeFitted, data: Samples) -> tuple[Method, Any, Samples]:
        """(downstream method, its fitted model, the samples it sees): e.g. for MoE gate weights."""
        down_data, _ = self._prepare_eval(fitted.upstreams, data)
        return fitted.downstream, fitted.fitted, down_data

    def explain(self, fitted: CascadeFitted, data: Samples) -> dict[str, list[np.ndarray]]:
        """The downstream's own series (e.g. its gate ``weights``) along the cascade's simulation, and each
        intermediate and surrogate as fed to the downstream (``"intermediate NAME"``, one column)."""
        down_data, _ = self._prepare_eval(fitted.upstreams, data)
        out = dict(fitted.downstream.explain(fitted.fitted, down_data))
        for n in self.surrogates + fitted.intermediates:
            j = down_data.input_names.index(n)
            out[f"intermediate {n}"] = [s.U[s.rows, j][:, None] for s in down_data.segments]
        return out


def _plain(v: Any) -> Any:
    return v.item() if hasattr(v, "item") else v


# -- the turboshaft-moe paper's Table 3 rows -------------------------------------------------
class MoENFIR(Cascade):
    """MoE for the target fed by the NFIR-reconstructed intermediate (turboshaft-moe: MoE-NFIR)."""

    name = "moe-nfir"
    family = "hybrid"
    summary = "MoE of the target fed by an NFIR reconstruction of the intermediate (e.g. WF -> TRQ)"
    preset = {"upstream": "nfir", "downstream": "moe", "source": "model"}


class SINDyNFIR(Cascade):
    """SINDy for the target fed by the NFIR-reconstructed intermediate (turboshaft-moe: SINDy-NFIR)."""

    name = "sindy-nfir"
    family = "data-driven"
    summary = "SINDy of the target fed by an NFIR reconstruction of the intermediate"
    preset = {"upstream": "nfir", "downstream": "sindy", "source": "model"}


class MoEMoE(Cascade):
    """MoE for the target fed by the upstream MoE's simulated intermediate (turboshaft-moe: MoE-MoE)."""

    name = "moe-moe"
    family = "hybrid"
    summary = "MoE of the target fed by the simulated intermediate of an upstream MoE"
    preset = {"upstream": "moe", "downstream": "moe", "source": "model"}


class MoEIdeal(Cascade):
    """MoE fed the measured intermediate at prediction: an ideal baseline, not available at run time."""

    name = "moe[ideal]"
    family = "hybrid"
    summary = "IDEAL baseline: MoE fed the measured intermediate (needs roles = { WF = 'input' }; not available at run time)"
    preset = {"downstream": "moe", "source": "true"}


class SINDyIdeal(Cascade):
    """SINDy fed the measured intermediate at prediction: an ideal baseline, not available at run time."""

    name = "sindy[ideal]"
    family = "data-driven"
    summary = "IDEAL baseline: SINDy fed the measured intermediate (needs roles = { WF = 'input' }; not available at run time)"
    preset = {"downstream": "sindy", "source": "true"}
