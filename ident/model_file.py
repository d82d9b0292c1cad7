"""One file format for every model bikeid identifies: :func:`save_model`, :func:`load_model`.

A saved model is a strict JSON object (no pickle; read back with
:func:`bikeid.sim.textformats.loads_json`)::

    {"format": "bikeid-model", "version": 1, "kind": "canonical-pem",
     "bikeid_version": "0.1.0", "created": "2026-11-24T08:30:00+00:00",
     "inputs": ["T_delta"], "outputs": ["phi", "phidot", "delta", "deltadot"],
     "sample_time": 0.005, "speeds": [5.0],
     "model": {...}, "provenance": [{"path": ..., "size": ..., "sha256": ...}],
     "settings": {...}, "results": {...}, "critical_speeds": {...}}

``kind`` (:data:`KINDS`) names the model class and the layout of ``model``:

- ``"canonical-pem"``: :class:`bikeid.ident.pem.CanonicalModel` (Chen & Dao's canonical
  model at one speed: theta, covariance, innovation gain K, ...);
- ``"speed-canonical-pem"``: :class:`bikeid.ident.pem.SpeedCanonicalModel` (the
  speed-parameterized model with each speed's fixed-speed fit);
- ``"direct"``: :class:`bikeid.ident.direct.DirectResult` (Moore & Hubbard's least squares
  or instrumental variables: M, C1, K0, K2, H, per-row covariances);
- ``"experiment-model"``: :class:`bikeid.ident.effects.experiment_model.ExperimentModel` (the
  steer-by-wire experiment with its fitted effects, ``bikeid measured fit``);
- ``"greybox"``: :class:`bikeid.ident.greybox.GreyboxModel` (the Whipple matrices with
  their free entries estimated: estimates, covariance, fixed values, free set, per-speed
  innovation gains, conditioning; ``bikeid identify --method greybox``).

Numbers are written with Python's shortest round-trip representation (``repr``), so a
loaded model holds the very same float64 values as the saved one: its eigenvalues and
simulations are equal bit for bit.  Units are those of the model classes (SI, radians;
see their docstrings).  Values that may legitimately be undefined (``cost`` of a model
derived at another speed, a VAF of a row without torque) are written ``null`` and read as
NaN; every other number must be finite.  ``sample_time`` [s] is null for a
continuous-time model identified without a sampling (direct); ``speeds`` [m/s] lists the
speeds the data covered (null when unknown).

``provenance`` lists each data file the model was identified from: absolute ``path``,
``size`` [bytes] and ``sha256`` of its bytes (:func:`file_provenance`).  ``settings`` holds
the method and its options as given by the caller; ``results`` any further fit results
(e.g. the effect selection log of ``measured fit``); both are stored verbatim.

``critical_speeds`` (models defined over speed only: speed-parameterized PEM, grey-box,
direct) holds the model's own answers, so a reader need not refit or recompute them:
``vmax`` [m/s] (the upper end of the search), ``v_d``, ``v_w``, ``v_c`` [m/s] (null where the
model has none in (0, vmax]; :func:`bikeid.sim.linear.critical_speeds`),
``weave_frequency`` [rad/s] at v_w (or null), ``intervals`` (the caller's
:meth:`bikeid.ident.uncertainty.CriticalSpeedIntervals.to_json`, or null) and ``note`` (why
there are no intervals, or null).  A fixed-speed model has none (the field is absent), and
files written before the field existed read back with :attr:`ModelFile.critical_speeds`
None (``model.critical_speeds()`` recomputes the values).

Version policy: ``version`` is incremented whenever a field changes meaning, unit or
layout, so that a reader never misreads a file; readers refuse a version they do not know
and name the versions they read.  New optional fields may be added without a new version
(older readers ignore unknown top-level fields).  Writes are atomic
(:func:`bikeid.dataset.files.atomic_write_text`): a failed save leaves an existing file
untouched.
"""

from __future__ import annotations

import datetime
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bikeid.dataset.files import atomic_write_text, check_output_path, sha256_file
from bikeid.dataset.tabular import relative_path
from bikeid.ident.canonical import SPEED_NAMES, THETA_NAMES
from bikeid.ident.direct import ALL_ENTRIES, DirectResult
from bikeid.ident.effects.experiment_model import DT as EXPERIMENT_DT
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.greybox import GreyboxModel
from bikeid.ident.methods import model_codecs, model_kinds
from bikeid.ident.pem import INPUT, CanonicalModel, SpeedCanonicalModel, output_matrix
from bikeid.sim.effect_files import declaration, declarations_from, register
from bikeid.sim.effect_registry import check_values, effect
from bikeid.sim.errors import InputError
from bikeid.sim.parameters import from_mapping
from bikeid.sim.textformats import loads_json

__all__ = [
    "FORMAT",
    "KINDS",
    "VERSION",
    "ModelFile",
    "file_provenance",
    "load_model",
    "read_model_file",
    "save_model",
]

FORMAT = "bikeid-model"
#: The format version written; :func:`read_model_file` reads exactly these versions.
VERSION = 1
READABLE_VERSIONS = (1,)
#: Model kinds and the class each is read back as: every identification method's
#: (:func:`bikeid.ident.methods.model_kinds`, from the one table of methods) and the
#: measured-data experiment model.
KINDS = {**model_kinds(), "experiment-model": ExperimentModel}
#: Largest model file read [bytes] (a PEM model with covariances is ~10 kB).
MAX_BYTES = 20_000_000
#: Inputs and outputs of the experiment model (external handlebar torque; measured states).
EXPERIMENT_INPUTS = ("T_ext",)
EXPERIMENT_OUTPUTS = ("phi", "delta", "phidot", "deltadot")
DIRECT_INPUTS = ("T_phi", "T_delta", "F")
DIRECT_OUTPUTS = ("phi", "delta", "phidot", "deltadot")
_FIX = "write it again with bikeid (identify --out, measured fit)"


@dataclass(frozen=True)
class ModelFile:
    """A model file read back: the model and everything saved with it.

    Attributes
    ----------
    model : CanonicalModel, SpeedCanonicalModel, DirectResult, ExperimentModel or GreyboxModel
        The model, equal bit for bit to the one saved.
    kind : str
        One of :data:`KINDS`.
    version : int
        Format version of the file.
    inputs, outputs : tuple of str
        Signal names of the model's inputs and outputs (bikeid names, SI units).
    sample_time : float or None
        Sample period [s] of the model's predictor, None for a continuous-time model.
    speeds : tuple of float or None
        Speeds [m/s] the data covered, None when not recorded.
    provenance : tuple of dict
        Per data file: ``path`` (str), ``size`` [bytes], ``sha256`` (hex).
    settings : dict
        Method and options, as saved.
    results : dict
        Further fit results, as saved.
    bikeid_version : str
        Version of bikeid that wrote the file.
    created : str
        Creation time, ISO 8601 with UTC offset.
    critical_speeds : dict or None
        For a model over speed: ``vmax``, ``v_d``, ``v_w``, ``v_c`` [m/s] (None where the
        model has none), ``weave_frequency`` [rad/s], ``intervals`` and ``note`` as saved
        (module docstring); None for a fixed-speed model or a file written without them.
    """

    model: Any
    kind: str
    version: int
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    sample_time: float | None
    speeds: tuple[float, ...] | None
    provenance: tuple[dict, ...] = ()
    settings: dict = field(default_factory=dict)
    results: dict = field(default_factory=dict)
    bikeid_version: str = ""
    created: str = ""
    critical_speeds: dict | None = None


# -- provenance --------------------------------------------------------------------------
def file_provenance(paths: Iterable[str | os.PathLike]) -> list[dict]:
    """Path, size and SHA-256 of each data file, as saved in ``provenance``.

    Parameters
    ----------
    paths : iterable of str or path-like
        The data files a model was identified from.

    Returns
    -------
    list of dict
        Per file ``{"path": path relative to the working directory (never a machine's
        absolute path; the file name alone when no relative path exists), "size": bytes,
        "sha256": hex digest}``.

    Raises
    ------
    InputError
        If a file cannot be read.
    """
    out = []
    for p in paths:
        path = Path(p).resolve()
        try:
            digest, size = sha256_file(path), path.stat().st_size
        except OSError as exc:
            raise InputError(f"cannot hash data file {str(path)!r}: {exc.strerror}") from None
        out.append({"path": relative_path(path), "size": int(size), "sha256": digest})
    return out


# -- writing -----------------------------------------------------------------------------
def _num(x: Any, what: str, nullable: bool = False) -> float | None:
    v = float(x)
    if not math.isfinite(v):
        if nullable and math.isnan(v):
            return None
        raise ValueError(
            f"cannot save the model: {what} is {v}; a saved model holds finite numbers"
        )
    return v


def _arr(a: Any, what: str) -> list:
    arr = np.asarray(a, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"cannot save the model: {what} holds NaN or infinite values")
    return arr.tolist()


def _canonical_section(m: CanonicalModel) -> dict:
    return {
        "parameter_names": list(THETA_NAMES),
        "theta": _arr(m.theta, "theta"),
        "covariance": _arr(m.covariance, "covariance"),
        "K": _arr(m.K, "K"),
        "dt": _num(m.dt, "dt"),
        "speed": _num(m.speed, "speed"),
        "noise_covariance": _arr(m.noise_covariance, "noise_covariance"),
        "outputs": list(m.outputs),
        "x0": [_arr(x, "x0") for x in m.x0],
        "cost": _num(m.cost, "cost", nullable=True),
        "nfev": int(m.nfev),
        "notes": [str(n) for n in m.notes],
        "noise_model": str(m.noise_model),
        "gain_noise": None if m.gain_noise is None else _arr(m.gain_noise, "gain_noise"),
        "noise_on_bound": [str(n) for n in m.noise_on_bound],
        "unstable_plant": str(m.unstable_plant),
        "roll_rms_deg": _num(m.roll_rms_deg, "roll_rms_deg", nullable=True),
    }


def _speed_section(m: SpeedCanonicalModel) -> dict:
    return {
        "parameter_names": list(SPEED_NAMES),
        "params": _arr(m.params, "params"),
        "covariance": _arr(m.covariance, "covariance"),
        "dt": _num(m.dt, "dt"),
        "g": _num(m.g, "g"),
        "outputs": list(m.outputs),
        "cost": _num(m.cost, "cost", nullable=True),
        "nfev": int(m.nfev),
        "per_speed": [_canonical_section(pm) for _, pm in sorted(m.per_speed.items())],
        "gain_noise": None if m.gain_noise is None else _arr(m.gain_noise, "gain_noise"),
        "notes": [str(n) for n in m.notes],
        "unstable_plant": str(m.unstable_plant),
        "roll_rms_deg": _num(m.roll_rms_deg, "roll_rms_deg", nullable=True),
    }


def _matrix_section(m: DirectResult | GreyboxModel) -> dict:
    """The Whipple matrices, H, g and the free entries with their standard errors."""
    return {
        "M": _arr(m.M, "M"),
        "C1": _arr(m.C1, "C1"),
        "K0": _arr(m.K0, "K0"),
        "K2": _arr(m.K2, "K2"),
        "H": _arr(m.H, "H"),
        "g": _num(m.g, "g"),
        "free": {k: _num(v, f"free[{k}]") for k, v in m.free.items()},
        "stderr": {k: _num(v, f"stderr[{k}]") for k, v in m.stderr.items()},
    }


def _direct_section(m: DirectResult) -> dict:
    return {
        **_matrix_section(m),
        "covariance": {
            row: {"names": list(names), "matrix": _arr(cov, f"covariance[{row}]")}
            for row, (names, cov) in m.covariance.items()
        },
        "condition": {k: _num(v, f"condition[{k}]") for k, v in m.condition.items()},
        "vaf_moore": {k: _num(v, "vaf_moore", nullable=True) for k, v in m.vaf_moore.items()},
        "vaf_variance": {
            k: _num(v, "vaf_variance", nullable=True) for k, v in m.vaf_variance.items()
        },
        "n_samples": int(m.n_samples),
        "method": str(m.method),
        "notes": [str(n) for n in m.notes],
    }


def _experiment_section(m: ExperimentModel) -> dict:
    out = {
        "effects": {k: _num(v, f"effect {k}") for k, v in m.effects.items()},
        "K": _num(m.K, "K"),
        "V": _num(m.V, "V"),
        "bicycle": m.p.name,
        "parameters": {k: _num(v, k) for k, v in m.p.as_dict().items()},
    }
    user = [declaration(effect(k)) for k in m.effects if effect(k).user]
    if user:  # a user's effects (--effects-file): declared again when the file is read
        out["user_effects"] = user
    return out


def _greybox_section(m: GreyboxModel) -> dict:
    return {
        **_matrix_section(m),
        "covariance": _arr(m.covariance, "covariance"),
        "condition": _num(m.condition, "condition"),
        "inflation": {k: _num(v, f"inflation[{k}]") for k, v in m.inflation.items()},
        "weakest": {k: _num(v, f"weakest[{k}]") for k, v in m.weakest.items()},
        "dropped": [str(n) for n in m.dropped],
        "fixed": {k: _num(v, f"fixed[{k}]") for k, v in m.fixed.items()},
        "symmetric": bool(m.symmetric),
        "K": [{"speed": _num(v, "K speed"), "gain": _arr(k, f"K[{v}]")} for v, k in m.K.items()],
        "dt": _num(m.dt, "dt"),
        "outputs": list(m.outputs),
        "speeds": [_num(v, "speeds") for v in m.speeds],
        "noise_covariance": _arr(m.noise_covariance, "noise_covariance"),
        "cost": _num(m.cost, "cost", nullable=True),
        "nfev": int(m.nfev),
        "notes": [str(n) for n in m.notes],
    }


def _kinds() -> dict[str, type]:
    """:data:`KINDS` now, with any method added to the table since import."""
    return {**model_kinds(), "experiment-model": ExperimentModel}


def _kind_of(model: Any) -> str:
    kinds = _kinds()
    # the most derived class first: a new method's model may subclass a built-in one
    for kind, cls in sorted(kinds.items(), key=lambda kc: -len(kc[1].__mro__)):
        if isinstance(model, cls):
            return kind
    raise TypeError(
        f"cannot save a {type(model).__name__}: save_model takes "
        + ", ".join(c.__name__ for c in kinds.values())
    )


def _summary(kind: str, model: Any) -> dict:
    codec = model_codecs().get(kind)
    if codec is not None:
        return dict(codec.summary(model))
    if kind == "canonical-pem":
        return {
            "inputs": [INPUT],
            "outputs": list(model.outputs),
            "sample_time": float(model.dt),
            "speeds": [float(model.speed)],
        }
    if kind == "speed-canonical-pem":
        return {
            "inputs": [INPUT],
            "outputs": list(model.outputs),
            "sample_time": float(model.dt),
            "speeds": [float(v) for v in sorted(model.per_speed)],
        }
    if kind == "greybox":
        return {
            "inputs": [INPUT],
            "outputs": list(model.outputs),
            "sample_time": float(model.dt),
            "speeds": [float(v) for v in model.speeds],
        }
    if kind == "direct":
        return {
            "inputs": list(DIRECT_INPUTS),
            "outputs": list(DIRECT_OUTPUTS),
            "sample_time": None,
            "speeds": None,
        }
    return {
        "inputs": list(EXPERIMENT_INPUTS),
        "outputs": list(EXPERIMENT_OUTPUTS),
        "sample_time": EXPERIMENT_DT,
        "speeds": None,
    }


_SECTIONS = {
    "canonical-pem": _canonical_section,
    "speed-canonical-pem": _speed_section,
    "direct": _direct_section,
    "experiment-model": _experiment_section,
    "greybox": _greybox_section,
}


def _provenance_entries(provenance: Sequence[Any] | None) -> list[dict]:
    out = []
    for item in provenance or ():
        if isinstance(item, (str, os.PathLike)):
            out += file_provenance([item])
        elif isinstance(item, Mapping) and {"path", "size", "sha256"} <= set(item):
            out.append(
                {
                    "path": str(item["path"]),
                    "size": int(item["size"]),
                    "sha256": str(item["sha256"]),
                }
            )
        else:
            raise ValueError(
                "provenance entries must be file paths or {'path', 'size', 'sha256'} objects"
            )
    return out


def _plain(obj: Any, where: str) -> Any:
    """Settings/results as plain JSON values (arrays to lists); NaN/inf refused."""
    if isinstance(obj, Mapping):
        return {str(k): _plain(v, f"{where}.{k}") for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v, where) for v in obj]
    if isinstance(obj, np.ndarray):
        return _plain(obj.tolist(), where)
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return _num(obj, where, nullable=True)
    if obj is None or isinstance(obj, str):
        return obj
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"cannot save {where}: {type(obj).__name__} is not a JSON value")


#: Upper end [m/s] of the critical-speed search saved with a model over speed (the default
#: of :meth:`bikeid.ident.linear_model.SpeedDependentModel.critical_speeds`).
CRITICAL_VMAX = 30.0
_CRITICAL_NAMES = ("v_d", "v_w", "v_c", "weave_frequency")


def _critical_section(
    model: Any, intervals: Mapping[str, Any] | None, note: str | None
) -> dict | None:
    """The ``critical_speeds`` field of a model over speed (None for a fixed-speed model)."""
    from bikeid.ident.linear_model import SpeedDependentModel

    if not isinstance(model, SpeedDependentModel):
        if intervals is not None or note is not None:
            raise ValueError(
                f"a fixed-speed {type(model).__name__} has no critical speeds: save "
                "critical_speed_intervals/critical_speeds_note with a model over speed only"
            )
        return None
    try:
        with np.errstate(all="ignore"):  # a degenerate model: no critical speeds, said so
            crit = model.critical_speeds(CRITICAL_VMAX)
    except (np.linalg.LinAlgError, ValueError, ArithmeticError) as exc:
        crit = {}
        note = f"{note}; " if note else ""
        note += f"no critical speeds: the model's matrices give none ({exc})"
    out: dict = {"vmax": CRITICAL_VMAX}
    for name in _CRITICAL_NAMES:
        v = crit.get(name)
        out[name] = None if v is None or not math.isfinite(v) else float(v)
    out["intervals"] = None if intervals is None else _plain(dict(intervals), "intervals")
    out["note"] = None if note is None else str(note)
    return out


def model_json(
    model: Any,
    *,
    provenance: Sequence[Any] | None = None,
    settings: Mapping[str, Any] | None = None,
    results: Mapping[str, Any] | None = None,
    speeds: Sequence[float] | None = None,
    critical_speed_intervals: Mapping[str, Any] | None = None,
    critical_speeds_note: str | None = None,
) -> str:
    """The text :func:`save_model` writes (same parameters, no file).

    Parameters
    ----------
    model : CanonicalModel, SpeedCanonicalModel, DirectResult, ExperimentModel or GreyboxModel
        The model.
    provenance : sequence of path or dict, optional
        Data files (hashed here) or entries of :func:`file_provenance`.
    settings : mapping, optional
        Method and options (JSON values; NumPy arrays and scalars are converted).
    results : mapping, optional
        Further fit results (JSON values).
    speeds : sequence of float, optional
        Speeds [m/s] of the data, for kinds that do not record them (direct, experiment).
    critical_speed_intervals : mapping, optional
        For a model over speed: its v_w, v_c intervals
        (:meth:`bikeid.ident.uncertainty.CriticalSpeedIntervals.to_json`), saved beside the
        critical speeds the model file computes and records itself.
    critical_speeds_note : str, optional
        For a model over speed: why there are no intervals (e.g. the data reject it).

    Returns
    -------
    str
        The JSON text, ending in a newline.

    Raises
    ------
    TypeError
        If ``model`` is not one of the saved classes or a setting is not a JSON value.
    ValueError
        If a model number is NaN or infinite where a finite value is required, or critical
        speed intervals or a note are given with a fixed-speed model.
    """
    import json

    from bikeid import __version__

    kind = _kind_of(model)
    summary = _summary(kind, model)
    if speeds is not None and summary["speeds"] is None:
        summary["speeds"] = [_num(v, "speeds") for v in speeds]
    obj = {
        "format": FORMAT,
        "version": VERSION,
        "kind": kind,
        "bikeid_version": __version__,
        "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        **summary,
        "model": _section(kind, model),
        "provenance": _provenance_entries(provenance),
        "settings": _plain(dict(settings or {}), "settings"),
        "results": _plain(dict(results or {}), "results"),
    }
    crit = _critical_section(model, critical_speed_intervals, critical_speeds_note)
    if crit is not None:
        obj["critical_speeds"] = crit
    return json.dumps(obj, indent=1, allow_nan=False) + "\n"


def save_model(
    model: Any,
    path: str | os.PathLike,
    *,
    provenance: Sequence[Any] | None = None,
    settings: Mapping[str, Any] | None = None,
    results: Mapping[str, Any] | None = None,
    speeds: Sequence[float] | None = None,
    critical_speed_intervals: Mapping[str, Any] | None = None,
    critical_speeds_note: str | None = None,
) -> Path:
    """Write a model file (module docstring), atomically.

    Parameters
    ----------
    model : CanonicalModel, SpeedCanonicalModel, DirectResult, ExperimentModel or GreyboxModel
        The identified model.
    path : str or path-like
        The JSON file to write (its folder is created if missing).
    provenance : sequence of path or dict, optional
        The data files the model comes from: paths (size and SHA-256 computed here) or
        entries of :func:`file_provenance`.
    settings : mapping, optional
        The method and its options (JSON values).
    results : mapping, optional
        Further fit results stored verbatim (JSON values).
    speeds : sequence of float, optional
        Speeds [m/s] of the data, for kinds that do not record them (direct, experiment).
    critical_speed_intervals : mapping, optional
        For a model over speed: its v_w, v_c intervals
        (:meth:`bikeid.ident.uncertainty.CriticalSpeedIntervals.to_json`), saved beside the
        critical speeds the model file computes and records itself.
    critical_speeds_note : str, optional
        For a model over speed: why there are no intervals (e.g. the data reject it).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    TypeError
        If ``model`` is not one of the saved classes.
    ValueError
        If ``path`` is not a regular file (a link, folder or device), a model number is
        NaN or infinite where a finite value is required, or critical-speed intervals or a
        note are given with a fixed-speed model.  Nothing is written then.
    """
    path = check_output_path(path)
    text = model_json(
        model, provenance=provenance, settings=settings, results=results, speeds=speeds,
        critical_speed_intervals=critical_speed_intervals,
        critical_speeds_note=critical_speeds_note,
    )  # fmt: skip
    atomic_write_text(path, text)
    return path


# -- reading -----------------------------------------------------------------------------
class _Reader:
    """Typed access to a parsed model file, each error naming the file and the field."""

    def __init__(self, where: str):
        self.where = where

    def fail(self, field_name: str, problem: str) -> InputError:
        return InputError(f"{self.where}: field {field_name!r} {problem}; {_FIX}")

    def get(self, obj: dict, key: str, prefix: str) -> Any:
        if not isinstance(obj, dict):
            raise self.fail(prefix.rstrip("."), "must be an object")
        if key not in obj:
            raise self.fail(prefix + key, "is missing")
        return obj[key]

    def number(self, obj: dict, key: str, prefix: str, nullable: bool = False) -> float:
        v = self.get(obj, key, prefix)
        if v is None and nullable:
            return float("nan")
        return self._float(v, prefix + key)

    def _float(self, v: Any, name: str) -> float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.fail(name, f"must be a number, got {type(v).__name__}")
        try:
            f = float(v)
        except OverflowError:
            f = math.inf
        if not math.isfinite(f):
            raise self.fail(name, "must be finite")
        return f

    def integer(self, obj: dict, key: str, prefix: str) -> int:
        v = self.get(obj, key, prefix)
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise self.fail(prefix + key, f"must be a non-negative integer, got {v!r}")
        return v

    def text(self, obj: dict, key: str, prefix: str) -> str:
        v = self.get(obj, key, prefix)
        if not isinstance(v, str):
            raise self.fail(prefix + key, f"must be a string, got {type(v).__name__}")
        return v

    def texts(self, obj: dict, key: str, prefix: str) -> tuple[str, ...]:
        v = self.get(obj, key, prefix)
        if not isinstance(v, list) or not all(isinstance(s, str) for s in v):
            raise self.fail(prefix + key, "must be a list of strings")
        return tuple(v)

    def array(self, obj: dict, key: str, prefix: str, shape: tuple) -> np.ndarray:
        """A float array of ``shape`` (None entries: any length)."""
        v = self.get(obj, key, prefix)
        return self._array(v, prefix + key, shape)

    def covariance(self, obj: dict, key: str, prefix: str, shape: tuple) -> np.ndarray:
        """A covariance matrix: symmetric and positive semi-definite.

        Tolerances: asymmetry up to 1e-9 and eigenvalues down to -1e-8 times the largest
        absolute entry / eigenvalue (round-off of a covariance computed in float64 is ~1e-16
        relative; the files keep every digit); a negative variance is never accepted.
        """
        c = self.array(obj, key, prefix, shape)
        if c.size == 0:
            return c
        scale = float(np.max(np.abs(c)))
        if np.any(np.diag(c) < 0):
            i = int(np.argmin(np.diag(c)))
            raise self.fail(prefix + key, f"has a negative variance {float(c[i, i]):.6g} at "
                            f"[{i}, {i}] (not a covariance)")  # fmt: skip
        if np.max(np.abs(c - c.T)) > 1e-9 * scale:
            raise self.fail(prefix + key, "is not symmetric (not a covariance)")
        if scale > 0:  # scaled first: a covariance of huge entries must not overflow
            u = c / scale
            try:
                low = float(np.linalg.eigvalsh(u / 2 + u.T / 2)[0])
            except np.linalg.LinAlgError:
                low = -np.inf
            if low < -1e-8:
                raise self.fail(prefix + key, f"is not positive semi-definite (eigenvalue "
                                f"{low * scale:.3g}; not a covariance)")  # fmt: skip
        return c

    def _array(self, v: Any, name: str, shape: tuple) -> np.ndarray:
        want = "x".join("n" if s is None else str(s) for s in shape)

        def walk(x: Any, depth: int) -> Any:
            if depth == len(shape):
                return self._float(x, name)
            if not isinstance(x, list):
                raise self.fail(name, f"must be a {want} array of numbers")
            return [walk(e, depth + 1) for e in x]

        rows = walk(v, 0)
        try:
            arr = np.array(rows, dtype=float)
        except ValueError:  # ragged
            raise self.fail(name, f"must be a {want} array of numbers") from None
        if arr.ndim != len(shape) or any(
            s is not None and n != s for n, s in zip(arr.shape, shape, strict=True)
        ):
            raise self.fail(name, f"must be a {want} array, got shape {arr.shape}")
        return arr

    def numbers(self, obj: dict, key: str, prefix: str, nullable: bool = False) -> dict:
        v = self.get(obj, key, prefix)
        if not isinstance(v, dict):
            raise self.fail(prefix + key, "must be an object of name: number")
        return {k: self.number(v, k, f"{prefix}{key}.", nullable) for k in v}

    def outputs(self, obj: dict, prefix: str) -> tuple[str, ...]:
        """The ``outputs`` field: measured states the canonical predictor accepts."""
        outputs = self.texts(obj, "outputs", prefix)
        try:
            output_matrix(outputs)
        except ValueError as exc:
            raise self.fail(prefix + "outputs", str(exc)) from None
        return outputs

    def sample_period(self, obj: dict, prefix: str) -> float:
        """The ``dt`` field: a positive sample period [s]."""
        dt = self.number(obj, "dt", prefix)
        if dt <= 0:
            raise self.fail(prefix + "dt", "must be a positive sample period [s]")
        return dt

    def names(self, obj: dict, key: str, prefix: str, expected: Sequence[str]) -> None:
        if list(self.texts(obj, key, prefix)) != list(expected):
            raise self.fail(prefix + key, f"must be {list(expected)} (this format's order)")


def _canonical_model(r: _Reader, sec: Any, prefix: str) -> CanonicalModel:
    r.names(sec, "parameter_names", prefix, THETA_NAMES)
    outputs = r.outputs(sec, prefix)
    n_out = len(outputs)
    dt = r.sample_period(sec, prefix)
    x0 = r.get(sec, "x0", prefix)
    if not isinstance(x0, list):
        raise r.fail(prefix + "x0", "must be a list of initial states")
    return CanonicalModel(
        theta=r.array(sec, "theta", prefix, (10,)),
        covariance=r.covariance(sec, "covariance", prefix, (10, 10)),
        K=r.array(sec, "K", prefix, (4, n_out)),
        dt=dt,
        speed=r.number(sec, "speed", prefix),
        noise_covariance=r.array(sec, "noise_covariance", prefix, (n_out, n_out)),
        outputs=outputs,
        x0=tuple(r._array(x, f"{prefix}x0[{i}]", (4,)) for i, x in enumerate(x0)),
        cost=r.number(sec, "cost", prefix, nullable=True),
        nfev=r.integer(sec, "nfev", prefix),
        notes=r.texts(sec, "notes", prefix),
        **_fit_facts(r, sec, prefix, gain=True),
    )


def _fit_facts(r: _Reader, sec: Any, prefix: str, gain: bool) -> dict:
    """How a PEM fit was made and what the interval functions check (``noise_model``, its
    noise parameters, ``unstable_plant``, ``roll_rms_deg``); absent in older files, whose
    models get the defaults (a free gain, nothing recorded).  The structure check is a
    verdict on the fitted runs, saved by ``bikeid identify`` as
    ``results.structure_check``, not with the model."""
    out: dict[str, Any] = {}
    if "unstable_plant" in sec:
        out["unstable_plant"] = str(r.get(sec, "unstable_plant", prefix))
    if "roll_rms_deg" in sec:
        out["roll_rms_deg"] = r.number(sec, "roll_rms_deg", prefix, nullable=True)
    if gain and "noise_model" in sec:
        out["noise_model"] = str(r.get(sec, "noise_model", prefix))
        out["noise_on_bound"] = r.texts(sec, "noise_on_bound", prefix)
        if sec.get("gain_noise") is not None:  # eta, its references, the sensor variances:
            # with angle-row noise and sensor ratios; without either (the previous release)
            L, raw = len(sec["outputs"]), sec.get("gain_noise")
            sizes = (3 + 2 + L, 5 + 4 + L, 5 + (L - 1) + 4 + L)  # the layouts, oldest first
            n = len(raw) if isinstance(raw, list) and len(raw) in sizes else sizes[-1]
            out["gain_noise"] = r.array(sec, "gain_noise", prefix, (n,))
    return out


def _speed_model(r: _Reader, sec: Any, prefix: str) -> SpeedCanonicalModel:
    r.names(sec, "parameter_names", prefix, SPEED_NAMES)
    per = r.get(sec, "per_speed", prefix)
    if not isinstance(per, list) or len(per) < 2:
        raise r.fail(prefix + "per_speed", "must list the fixed-speed fits of >= 2 speeds")
    models = [_canonical_model(r, s, f"{prefix}per_speed[{i}].") for i, s in enumerate(per)]
    outputs = r.texts(sec, "outputs", prefix)
    if any(m.outputs != outputs for m in models):
        raise r.fail(prefix + "per_speed", "must use the same outputs as the joint model")
    dt = r.sample_period(sec, prefix)
    return SpeedCanonicalModel(
        params=r.array(sec, "params", prefix, (14,)),
        covariance=r.covariance(sec, "covariance", prefix, (14, 14)),
        per_speed={round(m.speed, 6): m for m in models},
        dt=dt,
        g=r.number(sec, "g", prefix),
        outputs=outputs,
        cost=r.number(sec, "cost", prefix, nullable=True),
        nfev=r.integer(sec, "nfev", prefix),
        gain_noise=(None if sec.get("gain_noise") is None  # absent in older files
                    else r.array(sec, "gain_noise", prefix, (5,))),
        notes=r.texts(sec, "notes", prefix) if "notes" in sec else (),
        **_fit_facts(r, sec, prefix, gain=False),
    )


def _matrix_fields(r: _Reader, sec: Any, prefix: str) -> dict:
    """M, C1, K0, K2, H, g, free and stderr of :func:`_matrix_section`, checked."""
    free = r.numbers(sec, "free", prefix)
    stderr = r.numbers(sec, "stderr", prefix)
    bad = [k for k in list(free) + list(stderr) if k not in ALL_ENTRIES]
    if bad:
        raise r.fail(prefix + "free", f"names unknown entries {bad}")
    return {
        **{k: r.array(sec, k, prefix, (2, 2)) for k in ("M", "C1", "K0", "K2")},
        "H": r.array(sec, "H", prefix, (2,)),
        "g": r.number(sec, "g", prefix),
        "free": free,
        "stderr": stderr,
    }


def _direct_model(r: _Reader, sec: Any, prefix: str) -> DirectResult:
    fields = _matrix_fields(r, sec, prefix)
    covs_in = r.get(sec, "covariance", prefix)
    if not isinstance(covs_in, dict):
        raise r.fail(prefix + "covariance", "must be an object of row: {names, matrix}")
    covs = {}
    for row, c in covs_in.items():
        names = r.texts(c, "names", f"{prefix}covariance.{row}.")
        n = len(names)
        covs[row] = (names, r.covariance(c, "matrix", f"{prefix}covariance.{row}.", (n, n)))
    return DirectResult(
        **fields,
        covariance=covs,
        condition=r.numbers(sec, "condition", prefix),
        vaf_moore=r.numbers(sec, "vaf_moore", prefix, nullable=True),
        vaf_variance=r.numbers(sec, "vaf_variance", prefix, nullable=True),
        n_samples=r.integer(sec, "n_samples", prefix),
        method=r.text(sec, "method", prefix),
        notes=r.texts(sec, "notes", prefix),
    )


def _experiment_model(r: _Reader, sec: Any, prefix: str) -> ExperimentModel:
    if isinstance(sec, dict) and "user_effects" in sec:  # declare them before the values
        register(declarations_from(sec["user_effects"], f"{r.where}: field "
                                   f"'{prefix}user_effects'", origin=r.where))  # fmt: skip
    effects = r.numbers(sec, "effects", prefix)
    try:
        check_values(effects, f"{r.where}: field '{prefix}effects'")
        p = from_mapping(r.numbers(sec, "parameters", prefix), name=r.text(sec, "bicycle", prefix))
        return ExperimentModel(
            p=p, effects=effects, K=r.number(sec, "K", prefix), V=r.number(sec, "V", prefix)
        )
    except InputError:
        raise
    except ValueError as exc:
        raise InputError(f"{r.where}: {exc}") from None


def _greybox_model(r: _Reader, sec: Any, prefix: str) -> GreyboxModel:
    outputs = r.outputs(sec, prefix)
    n_out = len(outputs)
    fields = _matrix_fields(r, sec, prefix)
    names = list(fields["free"])
    for key in ("stderr", "inflation", "weakest"):
        if list(r.numbers(sec, key, prefix)) != names:
            raise r.fail(prefix + key, f"must name the free entries {names} in order")
    fixed = r.numbers(sec, "fixed", prefix)
    dropped = r.texts(sec, "dropped", prefix)
    bad = [k for k in list(fixed) + list(dropped) if k not in ALL_ENTRIES]
    if bad or not names:
        raise r.fail(prefix + "fixed", f"must name matrix entries; unknown {bad}")
    symmetric = r.get(sec, "symmetric", prefix)
    if not isinstance(symmetric, bool):
        raise r.fail(prefix + "symmetric", "must be true or false")
    dt = r.sample_period(sec, prefix)
    gains = r.get(sec, "K", prefix)
    if not isinstance(gains, list) or not gains:
        raise r.fail(prefix + "K", "must list {speed, gain} per speed")
    K = {}
    for i, e in enumerate(gains):
        pre = f"{prefix}K[{i}]."
        K[r.number(e, "speed", pre)] = r.array(e, "gain", pre, (4, n_out))
    speeds = tuple(float(v) for v in r.array(sec, "speeds", prefix, (None,)))
    if list(K) != list(speeds):
        raise r.fail(prefix + "K", f"must hold one gain per speed of 'speeds' {list(speeds)}")
    P = len(names)
    return GreyboxModel(
        **fields,
        covariance=r.covariance(sec, "covariance", prefix, (P, P)),
        condition=r.number(sec, "condition", prefix),
        inflation=r.numbers(sec, "inflation", prefix),
        weakest=r.numbers(sec, "weakest", prefix),
        dropped=dropped,
        fixed=fixed,
        symmetric=symmetric,
        K=K,
        dt=dt,
        outputs=outputs,
        speeds=speeds,
        noise_covariance=r.array(sec, "noise_covariance", prefix, (n_out, n_out)),
        cost=r.number(sec, "cost", prefix, nullable=True),
        nfev=r.integer(sec, "nfev", prefix),
        notes=r.texts(sec, "notes", prefix),
    )


def _section(kind: str, model: Any) -> dict:
    if kind in _SECTIONS:
        return _SECTIONS[kind](model)
    return _plain(model_codecs()[kind].write(model), "model")


def _read_section(r: _Reader, kind: str, sec: Any, prefix: str) -> Any:
    if kind in _READERS:
        return _READERS[kind](r, sec, prefix)
    if not isinstance(sec, dict):
        raise r.fail("model", "must be a JSON object")
    try:
        return model_codecs()[kind].read(sec)
    except (ValueError, TypeError, KeyError) as exc:
        raise r.fail("model", f"cannot be read as a {kind!r} model ({exc})") from None


_READERS = {
    "canonical-pem": _canonical_model,
    "speed-canonical-pem": _speed_model,
    "direct": _direct_model,
    "experiment-model": _experiment_model,
    "greybox": _greybox_model,
}


def _text_of(path: Path, where: str) -> str:
    try:
        size = path.stat().st_size
        if size > MAX_BYTES:
            raise InputError(
                f"{where} is {size:,} bytes, more than a model file's {MAX_BYTES:,}; give a "
                "model file written by bikeid"
            )
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{where} does not exist; {_FIX}") from None
    except IsADirectoryError:
        raise InputError(f"{where} is a folder; give the model's JSON file") from None
    except UnicodeDecodeError:
        raise InputError(
            f"{where} is not text (a run file or an image?); give the model's JSON file "
            "(written by bikeid identify --out or bikeid measured fit --out)"
        ) from None
    except OSError as exc:
        raise InputError(f"cannot read {where}: {exc}") from None


def model_from_text(text: str, where: str = "model file") -> ModelFile:
    """Parse and validate the text of a model file (:func:`read_model_file` without a file).

    Parameters
    ----------
    text : str
        The JSON text.
    where : str, optional
        Names the source in messages.

    Returns
    -------
    ModelFile
        The model and everything saved with it.

    Raises
    ------
    InputError
        As :func:`read_model_file`.
    """
    obj = loads_json(text, where)
    r = _Reader(where)
    if not isinstance(obj, dict):
        raise InputError(f"{where} must hold a JSON object, got {type(obj).__name__}; {_FIX}")
    if obj.get("format") != FORMAT:
        raise InputError(
            f"{where}: field 'format' is {obj.get('format')!r}, not {FORMAT!r}: this is not a "
            f"bikeid model file; {_FIX}"
        )
    version = obj.get("version")
    if isinstance(version, bool) or version not in READABLE_VERSIONS:
        raise InputError(
            f"{where}: field 'version' is {version!r}; this bikeid reads model files of version "
            f"{', '.join(map(str, READABLE_VERSIONS))}: upgrade bikeid, or {_FIX}"
        )
    kind = obj.get("kind")
    kinds = _kinds()
    if not isinstance(kind, str) or kind not in kinds:
        raise InputError(
            f"{where}: field 'kind' is {kind!r}; known kinds are {', '.join(kinds)}: upgrade "
            f"bikeid, or {_FIX}"
        )
    model = _read_section(r, kind, r.get(obj, "model", ""), "model.")
    prov = r.get(obj, "provenance", "")
    if not isinstance(prov, list):
        raise r.fail("provenance", "must be a list of {path, size, sha256}")
    entries = []
    for i, e in enumerate(prov):
        pre = f"provenance[{i}]."
        sha = r.text(e, "sha256", pre)
        if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
            raise r.fail(pre + "sha256", "must be 64 lowercase hexadecimal digits")
        entries.append(
            {"path": r.text(e, "path", pre), "size": r.integer(e, "size", pre), "sha256": sha}
        )
    settings, results = r.get(obj, "settings", ""), obj.get("results", {})
    for name, val in (("settings", settings), ("results", results)):
        if not isinstance(val, dict):
            raise r.fail(name, "must be an object")
    summary = _summary(kind, model)
    inputs, outputs = r.texts(obj, "inputs", ""), r.texts(obj, "outputs", "")
    if list(inputs) != summary["inputs"] or list(outputs) != summary["outputs"]:
        raise r.fail(
            "outputs",
            f"and 'inputs' disagree with the model's {summary['outputs']} / "
            f"{summary['inputs']} (edited by hand?)",
        )
    dt = None if obj.get("sample_time") is None else r.number(obj, "sample_time", "")
    if dt != summary["sample_time"]:
        raise r.fail("sample_time", f"disagrees with the model's {summary['sample_time']}")
    speeds = obj.get("speeds")
    if speeds is not None:
        speeds = tuple(float(v) for v in r._array(speeds, "speeds", (None,)))
    return ModelFile(
        model=model,
        kind=kind,
        version=version,
        inputs=inputs,
        outputs=outputs,
        sample_time=dt,
        speeds=speeds,
        provenance=tuple(entries),
        settings=settings,
        results=results,
        bikeid_version=r.text(obj, "bikeid_version", ""),
        created=r.text(obj, "created", ""),
        critical_speeds=_read_critical(r, obj, model),
    )


def _read_critical(r: _Reader, obj: dict, model: Any) -> dict | None:
    """The saved ``critical_speeds`` (None when absent: a fixed-speed model, an older file)."""
    from bikeid.ident.linear_model import SpeedDependentModel

    sec = obj.get("critical_speeds")
    if sec is None:
        return None
    if not isinstance(model, SpeedDependentModel):
        raise r.fail("critical_speeds", f"is given for a fixed-speed {type(model).__name__}, "
                     "which has none (edited by hand?)")  # fmt: skip
    out: dict = {"vmax": r.number(sec, "vmax", "critical_speeds.")}
    for name in _CRITICAL_NAMES:
        v = r.number(sec, name, "critical_speeds.", nullable=True)
        out[name] = None if math.isnan(v) else v
    intervals, note = sec.get("intervals"), sec.get("note")
    if intervals is not None and not isinstance(intervals, dict):
        raise r.fail("critical_speeds.intervals", "must be an object or null")
    if note is not None and not isinstance(note, str):
        raise r.fail("critical_speeds.note", "must be a string or null")
    out["intervals"], out["note"] = intervals, note
    return out


def read_model_file(path: str | os.PathLike) -> ModelFile:
    """Read and validate a model file: the model with its provenance and settings.

    Parameters
    ----------
    path : str or path-like
        A file written by :func:`save_model`.

    Returns
    -------
    ModelFile
        The model (equal bit for bit to the saved one) and everything saved with it.

    Raises
    ------
    InputError
        Naming the file, the field and the fix, if the file is missing, unreadable or
        larger than :data:`MAX_BYTES`, not strict JSON (truncated, duplicate keys, NaN;
        :func:`bikeid.sim.textformats.loads_json`), not a bikeid model file (``format``),
        of an unknown ``version`` or ``kind``, lacks a field, or has a field of the wrong
        type or shape or a number that is not finite.
    """
    path = Path(path)
    where = f"model file {str(path)!r}"
    return model_from_text(_text_of(path, where), where)


def load_model(path: str | os.PathLike) -> Any:
    """Read a model file and return the model object.

    Parameters
    ----------
    path : str or path-like
        A file written by :func:`save_model` (``bikeid identify --out``, ``bikeid measured
        fit``).

    Returns
    -------
    CanonicalModel, SpeedCanonicalModel, DirectResult, ExperimentModel or GreyboxModel
        The saved model, by the file's ``kind``; equal bit for bit to the saved one.
        :func:`read_model_file` also returns the provenance, settings and results.

    Raises
    ------
    InputError
        As :func:`read_model_file`.
    """
    return read_model_file(path).model
