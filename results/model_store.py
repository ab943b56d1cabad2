"""Stored models: one job's fitted model in a file that runs no code when read (``docs/models.md``).

A run with ``[store] models = true`` (or ``run --keep-models``) writes ``models/<job-key>.npz`` next to the
job's file: a zip (numpy's ``.npz`` layout) of

* ``model.json``: format name and version, the method's registered name and options, the selected
  hyperparameters, the data's names, units, sample period and mode, the package versions, the fitted
  model's state as a JSON tree whose arrays point to members ``a<i>.npy``, and the SHA-256 of all of it
  (``content_sha256``: the JSON without that field, then every array's name, dtype, shape and bytes);
* ``a<i>.npy``: the arrays, read with ``allow_pickle=False``;
* ``c<i>.npy``: the check data, the test part's segments as the job predicted them (inputs, initial
  outputs, the evaluated rows) and the job's predictions, so that a loaded model can prove that it
  predicts what the run tested (``StoredModel.check``) and an export can be compared against them.

The state tree comes from the method's ``model_state`` hook (the default: the fitted object itself) and
holds only numbers, text, lists, ``{"~tuple": [...]}``, ``{"~dict": {...}}``, arrays, torch tensors (as
arrays), scikit-learn's ``StandardScaler`` (its fitted arrays) and dataclasses, named by module and class
and rebuilt field by field without calling the class: a dataclass is only rebuilt from a module of
enginebench or of the stored method's own package. Anything else is refused when the run stores it,
with one line naming the type ("not storable"). Nothing here names a method.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import io
import json
import math
import platform
import time
import zipfile
from dataclasses import dataclass
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from enginebench.errors import MethodError, StoreError

FORMAT = "enginebench-model"
FORMAT_VERSION = 1
MODELS_DIR = "models"
MODEL_META = "stored_model"
"""The key under which a job's metadata brings its model file's bytes to ``Run.write_job``."""
JSON_MEMBER = "model.json"
PACKAGES = ("enginebench", "numpy", "scipy", "scikit-learn", "torch")
TRUSTED_SCALERS = ("sklearn.preprocessing._data:StandardScaler",)
"""scikit-learn classes stored by their fitted arrays (``get_params`` and the attributes ending in ``_``)."""


# --------------------------------------------------------------------------- the state tree
class _Encoder:
    def __init__(self, allowed_roots: Sequence[str]) -> None:
        self.arrays: list[np.ndarray] = []
        self.allowed = tuple(allowed_roots)

    def array(self, value: np.ndarray) -> int:
        if value.dtype.hasobject:
            raise MethodError(f"an array of Python objects (dtype {value.dtype}) is not storable")
        self.arrays.append(np.ascontiguousarray(value))
        return len(self.arrays) - 1

    def encode(self, obj: Any, where: str = "model") -> Any:
        if obj is None or isinstance(obj, (bool, str)):
            return obj
        if isinstance(obj, int) and not isinstance(obj, bool):
            return obj
        if isinstance(obj, float):
            return obj if math.isfinite(obj) else {"~float": repr(obj)}
        if isinstance(obj, np.ndarray):
            return {"~array": self.array(obj)}
        if isinstance(obj, np.generic):
            return {"~scalar": self.array(np.asarray(obj))}
        if isinstance(obj, tuple) and not hasattr(obj, "_fields"):
            return {"~tuple": [self.encode(v, f"{where}[{i}]") for i, v in enumerate(obj)]}
        if isinstance(obj, list):
            return [self.encode(v, f"{where}[{i}]") for i, v in enumerate(obj)]
        if isinstance(obj, dict):
            bad = [k for k in obj if not isinstance(k, str)]
            if bad:
                raise MethodError(f"{where} is a dict with a key that is not text ({bad[0]!r}): not storable")
            return {"~dict": {k: self.encode(v, f"{where}.{k}") for k, v in obj.items()}}
        name = f"{type(obj).__module__}:{type(obj).__qualname__}"
        if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
            if not type(obj).__module__.startswith(self.allowed):
                raise MethodError(f"{where} is a {name} from outside enginebench and the method's package: not storable")
            return {"~dataclass": name,
                    "fields": {f.name: self.encode(getattr(obj, f.name), f"{where}.{f.name}")
                               for f in dataclasses.fields(obj)}}
        if type(obj).__module__.startswith("torch") and type(obj).__name__ == "Tensor":
            return {"~tensor": self.array(obj.detach().cpu().numpy())}
        if name in TRUSTED_SCALERS:
            attrs = {k: v for k, v in vars(obj).items() if k.endswith("_") and not k.startswith("_")}
            return {"~sklearn": name, "params": self.encode(obj.get_params(), f"{where}.params"),
                    "attrs": self.encode(attrs, f"{where}.attrs")}
        raise MethodError(f"{where} is a {name}, which has no safe stored format here: not storable")


def _decode(tree: Any, arrays: Sequence[np.ndarray], allowed: Sequence[str]) -> Any:
    if isinstance(tree, list):
        return [_decode(v, arrays, allowed) for v in tree]
    if not isinstance(tree, dict):
        return tree
    if "~float" in tree:
        return float(tree["~float"])
    if "~array" in tree:
        return arrays[tree["~array"]]
    if "~scalar" in tree:
        return arrays[tree["~scalar"]][()]
    if "~tuple" in tree:
        return tuple(_decode(v, arrays, allowed) for v in tree["~tuple"])
    if "~dict" in tree:
        return {k: _decode(v, arrays, allowed) for k, v in tree["~dict"].items()}
    if "~tensor" in tree:
        import torch

        return torch.from_numpy(np.array(arrays[tree["~tensor"]]))
    if "~sklearn" in tree:
        if tree["~sklearn"] not in TRUSTED_SCALERS:
            raise StoreError(f"stored model: class {tree['~sklearn']} is not one a stored model may hold")
        cls = _class(tree["~sklearn"], ("sklearn.",))
        obj = cls(**_decode(tree["params"], arrays, allowed))
        for key, value in _decode(tree["attrs"], arrays, allowed).items():
            setattr(obj, key, value)
        return obj
    if "~dataclass" in tree:
        cls = _class(tree["~dataclass"], allowed)
        if not dataclasses.is_dataclass(cls):
            raise StoreError(f"stored model: {tree['~dataclass']} is not a dataclass")
        obj = object.__new__(cls)  # field by field: no __init__ or __post_init__ runs
        values = {k: _decode(v, arrays, allowed) for k, v in tree["fields"].items()}
        for f in dataclasses.fields(cls):
            object.__setattr__(obj, f.name, values[f.name] if f.name in values else _default(f))
        return obj
    raise StoreError(f"stored model: an entry {sorted(tree)!r} of its state is not one this format knows")


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:  # type: ignore[misc]
        return f.default_factory()  # type: ignore[misc]
    raise StoreError(f"stored model: field {f.name!r} is missing from its state")


def _class(name: str, allowed: Sequence[str]) -> type:
    module, _, qualname = name.partition(":")
    if not module.startswith(tuple(allowed)):
        raise StoreError(f"stored model: class {name} is outside the packages a stored model may name "
                         f"({', '.join(a.rstrip('.') for a in allowed)})")
    obj: Any = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def _roots(method_cls: type) -> tuple[str, ...]:
    """Module prefixes whose dataclasses a method's stored state may name: enginebench's and the method's package."""
    own = method_cls.__module__.split(".")[0]
    return tuple(dict.fromkeys(("enginebench.", f"{own}.", method_cls.__module__)))


# --------------------------------------------------------------------------- check data
def check_arrays(samples: Any, predictions: Sequence[np.ndarray]) -> tuple[dict[str, Any], list[np.ndarray]]:
    """The evaluated part's segments (``Samples``) and the job's predictions of them as JSON plus arrays."""
    arrays: list[np.ndarray] = []
    segments = []

    def put(value: Any) -> int | None:
        if value is None:
            return None
        arrays.append(np.ascontiguousarray(value))
        return len(arrays) - 1

    for s, p in zip(samples.segments, predictions):
        segments.append({"id": s.id, "X": put(s.X), "rows": put(s.rows), "U": put(s.U), "t": put(s.t),
                         "y0": put(s.y0), "y_init": put(s.y_init), "prediction": put(np.asarray(p, dtype=float))})
    return {"segments": segments}, arrays


# --------------------------------------------------------------------------- writing
def versions() -> dict[str, str | None]:
    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            out[name] = importlib_metadata.version(name)
        except importlib_metadata.PackageNotFoundError:
            out[name] = None
    return out


def _npy(value: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, value, allow_pickle=False)
    return buf.getvalue()


def content_sha256(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> str:
    """SHA-256 of a stored model's content: its JSON (without ``sha256``, keys sorted) and each array's name,
    dtype, shape and bytes, in name order. A byte that changes any of them changes the digest."""
    h = hashlib.sha256(b"enginebench model v1\0")
    body = json.dumps({k: v for k, v in meta.items() if k != "sha256"}, sort_keys=True).encode()
    h.update(len(body).to_bytes(8, "little") + body)
    for name in sorted(arrays):
        a = arrays[name]
        h.update(f"\0{name}\0{a.dtype.str}\0{a.shape}\0".encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def encode_model(method: Any, fitted: Any, *, data: Any, params: dict[str, Any], job: dict[str, Any],
                 check: tuple[Any, Sequence[np.ndarray]] | None = None) -> bytes:
    """The bytes of a stored model: ``method``'s ``model_state(fitted)`` and the context to predict with it.

    ``data`` is the job's evaluated ``Samples`` (names, units, dt, mode), ``check`` (samples, predictions)
    the test part as the job predicted it. MethodError (one line, "not storable") when the state holds an
    object with no safe format.
    """
    from enginebench.results.job_files import jsonable

    encoder = _Encoder(_roots(type(method)))
    try:
        state = encoder.encode(method.model_state(fitted))
    except MethodError as exc:
        raise MethodError(f"method {method.name!r}: its fitted model is not storable ({exc})") from None
    arrays = {f"a{i}": a for i, a in enumerate(encoder.arrays)}
    meta: dict[str, Any] = {
        "format": FORMAT, "format_version": FORMAT_VERSION,
        "method": method.name, "class": f"{type(method).__module__}:{type(method).__qualname__}",
        "options": jsonable(method.options), "params": jsonable(params), "job": jsonable(job),
        "data": {"mode": data.mode, "window": float(data.window), "dt": float(data.dt),
                 "feature_names": list(data.feature_names), "input_names": list(data.input_names),
                 "target_names": list(data.target_names), "internal_names": list(data.internal_names),
                 "units": dict(data.units), "init_samples": int(data.init_samples)},
        "state": state, "versions": versions(), "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    if check is not None:
        tree, extra = check_arrays(*check)
        meta["check"] = {"part": "test", **tree}
        arrays.update({f"c{i}": a for i, a in enumerate(extra)})
    meta["sha256"] = content_sha256(meta, arrays)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(JSON_MEMBER, json.dumps(meta, indent=1))
        for name, a in arrays.items():
            zf.writestr(f"{name}.npy", _npy(a))
    return buf.getvalue()


# --------------------------------------------------------------------------- reading
def read_model_file(path: str | Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """A stored model's JSON and arrays, checked against its SHA-256; StoreError (one line) otherwise."""
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as zf:
            meta = json.loads(zf.read(JSON_MEMBER))
            arrays = {}
            for info in zf.infolist():
                if info.filename.endswith(".npy"):
                    with zf.open(info) as fh:
                        arrays[info.filename[:-4]] = np.lib.format.read_array(fh, allow_pickle=False)
    except FileNotFoundError:
        raise StoreError(f"{path}: no stored model there; store one with `enginebench run --keep-models`") from None
    except (OSError, KeyError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise StoreError(f"{path}: not a readable stored model ({type(exc).__name__}: {exc}); "
                         "it is refused") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise StoreError(f"{path}: not an enginebench stored model (no format {FORMAT!r} in its {JSON_MEMBER})")
    if meta.get("format_version") != FORMAT_VERSION:
        raise StoreError(f"{path}: stored model format version {meta.get('format_version')!r}; this enginebench "
                         f"reads version {FORMAT_VERSION}")
    if content_sha256(meta, arrays) != meta.get("sha256"):
        raise StoreError(f"{path}: the stored model does not match its SHA-256 checksum (a changed byte); "
                         "it is refused")
    recorded = _recorded_file_sha(path)
    if recorded is not None and recorded != hashlib.sha256(path.read_bytes()).hexdigest():
        raise StoreError(f"{path}: the file does not match the SHA-256 its run's job file records; it is refused")
    return meta, arrays


def _recorded_file_sha(path: Path) -> str | None:
    """The SHA-256 a run's job file records for a model file inside that run's models/ folder (None elsewhere)."""
    if path.parent.name != MODELS_DIR:
        return None
    job = path.parent.parent / "jobs" / f"{path.name[:-len('.npz')]}.parquet"
    if not job.is_file():
        return None
    from enginebench.results.job_files import load_job

    try:
        meta = load_job(job, frame=False)[1]
    except Exception:  # noqa: BLE001 - a damaged job file is reported by the run; the content digest still holds
        return None
    record = meta.get("model_file")
    return record.get("sha256") if isinstance(record, dict) else None


@dataclass
class StoredModel:
    """A loaded model: ``simulate(u, y_init)`` (simulation mode) or ``predict(X)`` run the method's own
    ``predict`` on the stored state, so they give what the run's job gave."""

    meta: dict[str, Any]
    method: Any
    fitted: Any
    check_data: list[dict[str, Any]]

    @property
    def mode(self) -> str:
        return self.meta["data"]["mode"]

    @property
    def dt(self) -> float:
        return float(self.meta["data"]["dt"])

    @property
    def input_names(self) -> tuple[str, ...]:
        return tuple(self.meta["data"]["input_names"])

    @property
    def target_names(self) -> tuple[str, ...]:
        return tuple(self.meta["data"]["target_names"])

    def samples(self, segments: Sequence[Any]) -> Any:
        from enginebench.samples import Samples

        d = self.meta["data"]
        return Samples(segments=tuple(segments), mode=d["mode"], window=d["window"], dt=d["dt"],
                       feature_names=tuple(d["feature_names"]), input_names=tuple(d["input_names"]),
                       target_names=tuple(d["target_names"]), internal_names=tuple(d["internal_names"]),
                       units=dict(d["units"]), init_samples=int(d["init_samples"]))

    def predict_samples(self, data: Any) -> list[np.ndarray]:
        """The method's predictions of ``data`` (a ``Samples`` without targets), one array per segment."""
        k = len(self.target_names)
        preds = self.method.predict(self.fitted, data)
        return [np.asarray(p, dtype=float).reshape(len(s), k) for p, s in zip(preds, data.segments)]

    def simulate(self, u: np.ndarray, y_init: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
        """Free run over inputs ``u`` (n, inputs) from measured outputs ``y_init`` (the run's ``init_samples``
        rows, at least one): the predictions of rows ``init_samples`` (or 0 without a window) to n - 1."""
        from enginebench.samples import SegmentSamples

        if self.mode != "simulation":
            raise StoreError(f"this stored model was tested in mode {self.mode!r}; use predict(X)")
        u = np.asarray(u, dtype=np.float64).reshape(len(u), -1)
        k = len(self.target_names)
        y_init = np.asarray(y_init, dtype=np.float64).reshape(-1, k)
        n_init = int(self.meta["data"]["init_samples"])
        if len(y_init) < max(n_init, 1):
            raise StoreError(f"simulate: y_init has {len(y_init)} rows; this model's runs start from "
                             f"{max(n_init, 1)} measured output row(s)")
        rows = np.arange(n_init, len(u))
        t = np.arange(len(u)) * self.dt if t is None else np.asarray(t, dtype=np.float64)
        seg = SegmentSamples(id="simulate", X=u[rows], rows=rows, U=u, t=t, y0=y_init[0], y_init=y_init[:n_init])
        return self.predict_samples(self.samples([seg]))[0]

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Predictions of feature rows ``X`` (n, features) (static and window modes)."""
        from enginebench.samples import SegmentSamples

        X = np.asarray(X, dtype=np.float64)
        n = len(X)
        U = X if X.shape[1] == len(self.input_names) else np.empty((n, 0))
        seg = SegmentSamples(id="predict", X=X, rows=np.arange(n), U=U, t=np.arange(n) * self.dt)
        return self.predict_samples(self.samples([seg]))[0]

    def check_segments(self) -> list[Any]:
        """The stored test part's segments, as the job predicted them (without targets)."""
        from enginebench.samples import SegmentSamples

        return [SegmentSamples(id=c["id"], X=c["X"], rows=c["rows"], U=c["U"], t=c["t"], y0=c["y0"],
                               y_init=c["y_init"]) for c in self.check_data]

    def test_predictions(self) -> list[np.ndarray]:
        """The job's predictions of its test part, one array per segment (stored with the model)."""
        return [c["prediction"] for c in self.check_data]

    def check(self) -> float:
        """The largest absolute difference between this model's predictions of the stored test part and the
        job's (0.0 when the round trip is exact)."""
        if not self.check_data:
            raise StoreError("this stored model holds no test predictions to check against")
        mine = self.predict_samples(self.samples(self.check_segments()))
        return max((float(np.max(np.abs(a - b), initial=0.0)) for a, b in zip(mine, self.test_predictions())),
                   default=0.0)


def load_model(path: str | Path) -> StoredModel:
    """Open a stored model (``models/<job-key>.npz`` of a run): checked, rebuilt without training anything."""
    from enginebench import registry

    meta, arrays = read_model_file(path)
    cls = registry.get(meta["method"])
    method = cls(**meta["options"])
    state = _decode(meta["state"], [arrays[f"a{i}"] for i in range(_count(arrays, "a"))], _roots(cls))
    fitted = method.model_from_state(state)
    check = []
    checks = [arrays[f"c{i}"] for i in range(_count(arrays, "c"))]
    for seg in meta.get("check", {}).get("segments", []):
        check.append({k: (v if k == "id" else None if v is None else checks[v]) for k, v in seg.items()})
    return StoredModel(meta=meta, method=method, fitted=fitted, check_data=check)


def _count(arrays: dict[str, np.ndarray], prefix: str) -> int:
    n = 0
    while f"{prefix}{n}" in arrays:
        n += 1
    return n


def model_path(run_path: str | Path, job_key: str) -> Path:
    return Path(run_path) / MODELS_DIR / f"{job_key}.npz"
