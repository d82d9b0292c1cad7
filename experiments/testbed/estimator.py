"""Anyone's estimator as one callable thing for the testbed studies (:class:`Estimator`).

An :class:`Estimator` is made from

- a name of the method table with optional settings (:func:`bikeid.ident.methods.resolve`:
  ``"pem"``, ``"pem:noise_model=none"``, the preset ``"direct_ls"``); the scenario's
  bicycle supplies the fixed entries of the direct and grey-box methods;
- a peer from the bench extra: ``"nfoursid"`` (``pip install 'bikeid[bench]'``), N4SID
  with input T_delta and outputs phi, delta, 40 block rows, order 4;
- ``"module:function"`` (importable from the current folder or ``PYTHONPATH``), or any
  Python callable.

A callable is called ``fn(runs, context)``: ``runs`` the scenario's runs of one seed and
length (one per speed; each carries its dither in ``run.dither`` [N m], the logged steer
torque ``T_delta`` and, on the linear plant, the true states in ``run.truth``);
``context`` a :class:`Context` with the scenario, the bicycle and the controller (for
indirect and two-stage methods).  It returns a
:class:`~bikeid.ident.linear_model.LinearModel` (fixed-speed or over speed), a
``control.StateSpace`` (continuous, or discrete with its dt: eigenvalues log(z)/dt), an
:class:`~bikeid.ident.methods.Identified`, or a mapping speed -> one of these.  If the
returned object has ``eigenvalue_intervals(level)`` (giving, per speed or for its one
speed, an object with ``values`` and ``std_real``, ``std_imag`` [1/s]), or is a canonical
PEM model (or a mapping of them) with its covariance, the study counts how often its
first-order intervals contain the truth.

:meth:`Estimator.estimate` reduces whatever came back to the four figures the studies
score per speed, :data:`COMPONENTS`: the weave's real and imaginary part and the capsize
and caster eigenvalues [1/s], the identified eigenvalues paired with the truth by minimum
total distance (:func:`pair`).
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bikeid.experiments.testbed.scenario import Scenario
from bikeid.sim.errors import InputError

__all__ = ["COMPONENTS", "PEERS", "Context", "Estimator", "pair"]

#: The figures scored per speed [1/s]: weave real and imaginary part, capsize, caster.
COMPONENTS = ("weave_re", "weave_im", "capsize", "caster")

#: Peers from the bench extra, by name.
PEERS = ("nfoursid",)


@dataclass(frozen=True)
class Context:
    """What a callable estimator may use besides the runs.

    Attributes
    ----------
    scenario : Scenario
        The study's scenario (dither, noise levels, speeds).
    bicycle : BicycleParameters
        The simulated bicycle (fixed entries of a grey-box method, say).
    controller : Controller
        A fresh instance of the loop's controller (its gains; for indirect methods).
    level : float
        The nominal level of the intervals the study counts.
    """

    scenario: Scenario
    bicycle: Any
    controller: Any
    level: float


def pair(found: Sequence[complex], truth: Sequence[complex]) -> np.ndarray:
    """The found eigenvalues that pair with ``truth`` (minimum total distance).

    Parameters
    ----------
    found : sequence of complex
        Identified eigenvalues [1/s], at least as many as ``truth``.
    truth : sequence of complex
        [weave, conj(weave), capsize, caster] [1/s].

    Returns
    -------
    ndarray of int
        Index into ``found`` of the partner of each truth value.

    Raises
    ------
    ValueError
        If fewer eigenvalues are found than there are truth values.
    """
    from scipy.optimize import linear_sum_assignment

    f = np.asarray(found, complex).ravel()
    t = np.asarray(truth, complex).ravel()
    if f.size < t.size:
        raise ValueError(f"the model has {f.size} eigenvalues; the truth has {t.size}")
    rows, cols = linear_sum_assignment(np.abs(t[:, None] - f[None, :]))
    out = np.empty(t.size, int)
    out[rows] = cols
    return out


def _components(values: np.ndarray, idx: np.ndarray) -> np.ndarray:
    w = values[idx[0]]
    return np.array([w.real, abs(w.imag), values[idx[2]].real, values[idx[3]].real])


def _load(spec: str) -> Callable[..., Any]:
    mod, _, fn = spec.partition(":")
    if os.getcwd() not in sys.path and "" not in sys.path:
        sys.path.insert(0, os.getcwd())  # "importable from the current folder"
    try:
        module = importlib.import_module(mod)
    except ImportError as exc:
        raise InputError(
            f"estimator {spec!r}: cannot import {mod!r} ({exc}); run from its "
            "folder or put that folder on PYTHONPATH"
        ) from None
    f = getattr(module, fn, None)
    if not callable(f):
        raise InputError(f"estimator {spec!r}: {mod} has no function {fn!r}")
    return f


class Estimator:
    """An estimator the studies can run: a table method, a peer or a callable.

    Parameters
    ----------
    spec : str or callable
        ``"NAME[:KEY=VALUE]..."`` of the method table, a peer of :data:`PEERS`,
        ``"module:function"``, or a callable ``fn(runs, context)``.
    name : str, optional
        The name in reports (default: ``spec``, or the callable's ``__name__``).

    Raises
    ------
    InputError
        If ``spec`` is none of these (the message lists the table's names).
    """

    def __init__(self, spec: str | Callable[..., Any], name: str | None = None) -> None:
        self.spec = spec
        if callable(spec):
            self.kind = "callable"
            self.name = name or getattr(spec, "__name__", "estimator")
            return
        if not isinstance(spec, str) or not spec.strip():
            raise InputError(
                f"estimator {spec!r}: give a method name, module:function or a callable"
            )
        text = spec.strip()
        self.name = name or text
        from bikeid.ident import methods

        head = text.split(":")[0]
        if head in methods.names():
            self.kind = "method"
            self.resolved = methods.resolve(text)  # settings checked here, once
        elif text in PEERS:
            self.kind = "peer"
        elif ":" in text and "=" not in text:
            self.kind = "module"
            _load(text)  # refuse now, one line, not on every seed
        else:
            raise InputError(
                f"estimator {text!r}: give one of {', '.join(methods.names())} "
                f"(settings as NAME:KEY=VALUE), a peer ({', '.join(PEERS)}), "
                "module:function or a callable"
            )

    def __repr__(self) -> str:
        return f"Estimator({self.name!r})"

    def __getstate__(self) -> dict[str, Any]:  # resolved again on the worker
        return {"spec": self.spec, "name": self.name}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["spec"], state["name"])  # type: ignore[misc]

    def fit(self, runs: Sequence[Any], context: Context) -> Any:
        """Run the estimator on one seed's runs.

        Parameters
        ----------
        runs : sequence of Run
            One run per speed.
        context : Context
            Scenario, bicycle, controller, level.

        Returns
        -------
        object
            What the estimator returned (:meth:`estimate` reads it).
        """
        if self.kind == "method":
            return self.resolved.fit(runs, reference=context.bicycle)
        if self.kind == "peer":
            return {r.speed: _nfoursid(r) for r in runs}
        fn = self.spec if self.kind == "callable" else _load(str(self.spec))
        return fn(list(runs), context)  # type: ignore[operator]

    def estimate(
        self, runs: Sequence[Any], context: Context, truth: Mapping[float, np.ndarray]
    ) -> dict[float, dict[str, Any]]:
        """Fit and reduce to :data:`COMPONENTS` per speed, with interval figures if any.

        Parameters
        ----------
        runs : sequence of Run
            One run per speed.
        context : Context
            Scenario, bicycle, controller, level.
        truth : mapping of float to ndarray
            Per speed [weave, conj(weave), capsize, caster] [1/s].

        Returns
        -------
        dict of float to dict
            Per speed: ``est`` (4 floats [1/s]) and, where the estimator gives intervals,
            ``se`` (4 first-order standard errors [1/s]).

        Raises
        ------
        Exception
            Whatever the estimator raises (the study counts the seed as refused), or
            InputError if what it returned has no model at a speed.
        """
        out = self.fit(runs, context)
        intervals = _intervals(out, context.level)
        res: dict[float, dict[str, Any]] = {}
        for v, t in truth.items():
            lam = _eigenvalues(out, v)
            idx = pair(lam, t)
            row: dict[str, Any] = {"est": _components(lam, idx).tolist()}
            ei = intervals.get(v) if intervals else None
            if ei is not None:
                j = pair(ei.values, t)
                sr, si = np.asarray(ei.std_real), np.asarray(ei.std_imag)
                row["se"] = [float(sr[j[0]]), float(si[j[0]]), float(sr[j[2]]), float(sr[j[3]])]
            res[v] = row
        return res


def _at(out: Any, speed: float) -> Any:
    if isinstance(out, Mapping):
        for k, m in out.items():
            if abs(float(k) - speed) < 1e-6:
                return m
        raise InputError(f"the estimator returned no model at {speed:g} m/s")
    return out


def _eigenvalues(out: Any, speed: float) -> np.ndarray:
    from bikeid.ident.linear_model import LinearModel, SpeedDependentModel
    from bikeid.ident.methods import Identified

    if isinstance(out, Identified):
        return np.asarray(out.eigenvalues(speed), complex)
    m = _at(out, speed)
    if isinstance(m, LinearModel):
        v = speed if isinstance(m, SpeedDependentModel) else None
        if v is None and getattr(m, "speed", speed) is not None:
            if abs(float(getattr(m, "speed", speed)) - speed) > 1e-6:
                raise InputError(
                    f"the estimator's model is at {m.speed:g} m/s, not "  # type: ignore[attr-defined]
                    f"{speed:g} m/s; return one per speed"
                )
        return np.asarray(m.eigenvalues(v), complex)
    A = getattr(m, "A", None)
    if A is not None:  # control.StateSpace
        lam = np.linalg.eigvals(np.asarray(A, float))
        dt = getattr(m, "dt", 0)
        if dt not in (None, 0, True):
            return np.log(lam.astype(complex)) / float(dt)
        if dt is True:
            raise InputError("the estimator returned a discrete StateSpace without its dt")
        return lam
    raise InputError(
        f"the estimator returned {type(m).__name__}; return a LinearModel, a "
        "control.StateSpace or a mapping speed -> one of these"
    )


def _given(model: Any, level: float) -> Any:
    """The model's first-order eigenvalue intervals, or None where they are withheld
    (ident.trust: a refused interval is no coverage figure, while the estimate still counts
    for bias and RMSE)."""
    from bikeid.ident.uncertainty import eigenvalue_intervals
    from bikeid.sim.errors import UntrustworthyResult

    try:
        return eigenvalue_intervals(model, level=level, method="delta")
    except UntrustworthyResult:
        return None


def _intervals(out: Any, level: float) -> dict[float, Any] | None:
    from bikeid.ident.methods import Identified

    if isinstance(out, Identified):
        if not out.interval_models:
            return None
        return {v: _given(m, level) for v, m in out.interval_models.items() if m is not None}
    from bikeid.ident.pem import CanonicalModel

    if isinstance(out, CanonicalModel) or (
        isinstance(out, Mapping)
        and out
        and all(isinstance(m, CanonicalModel) for m in out.values())
    ):  # canonical models carry their covariance: first-order intervals
        models = out if isinstance(out, Mapping) else {out.speed: out}
        return {float(v): _given(m, level) for v, m in models.items()}
    f = getattr(out, "eigenvalue_intervals", None)
    if not callable(f):
        return None
    ei = f(level)
    if isinstance(ei, Mapping):
        return {float(k): e for k, e in ei.items()}
    return {float(ei.speed): ei}


def _nfoursid(run) -> Any:
    """The nfoursid peer at one run: N4SID, input T_delta, outputs phi and delta, 40 block
    rows, order 4 (``benchmarks/bench_peer.py``'s settings); a discrete StateSpace."""
    try:
        import pandas as pd
        from nfoursid.nfoursid import NFourSID
    except ImportError:
        raise InputError(
            "estimator 'nfoursid' needs the bench extra: pip install 'bikeid[bench]'"
        ) from None
    import control

    frame = pd.DataFrame({k: np.asarray(run[k]) for k in ("T_delta", "phi", "delta")})
    n4 = NFourSID(
        frame, output_columns=["phi", "delta"], input_columns=["T_delta"], num_block_rows=40
    )
    n4.subspace_identification()
    ss, _ = n4.system_identification(rank=4)
    return control.ss(ss.a, ss.b, ss.c, ss.d, run.dt)


def module_file_of(spec: str) -> Path | None:
    """The file of the module named by ``module:function`` (None if not a plain module).

    Parameters
    ----------
    spec : str
        ``module:function``.

    Returns
    -------
    Path or None
        Its ``.py`` file, or None for a package or a compiled module.
    """
    mod = importlib.import_module(spec.partition(":")[0])
    f = getattr(mod, "__file__", None)
    if f is None or Path(f).name == "__init__.py" or not f.endswith(".py"):
        return None
    return Path(f)
