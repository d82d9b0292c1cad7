"""The identification methods as one table: name -> fit function, model class, file kind.

:data:`METHODS` maps each method name to a :class:`Method`: its fit function (one signature
for all, returning an :class:`Identified`), its settings type (a frozen dataclass with named
defaults), the model classes it returns, the model-file kinds they are saved as
(:mod:`bikeid.ident.model_file`) and a one-line description.  ``bikeid identify``,
``bikeid identify accuracy``, the Moore & Hubbard reproduction, the measured-data study and
the model loader read it, so a name means one estimator everywhere:

- ``"direct"``: Moore & Hubbard's least squares (or instrumental variables) of the equations
  of motion, :func:`bikeid.ident.direct.identify`, on signals prepared by
  :func:`bikeid.ident.signals.prepare`.  Its settings (:class:`DirectSettings`) are the
  derivative (``interval``, ``central``, ``forward``, ``backward``), the low-pass cut-off
  [Hz] and the instruments (none = least squares); the named presets
  (:data:`DIRECT_PRESETS`) are bikeid's default, Moore & Hubbard's published processing
  (central differences, 15 Hz) and the testbed's IV on the external signals.
- ``"pem"``: Chen & Dao's canonical prediction-error model per speed
  (:func:`bikeid.ident.pem.fit`), or one over all speeds (``speed_parameterized``,
  :func:`bikeid.ident.pem.fit_speed_model`); :class:`PemSettings`.
- ``"greybox"``: prediction-error fit of chosen entries of M, C1, K0, K2
  (:func:`bikeid.ident.greybox.fit`), one over all speeds; :class:`GreyboxSettings`.

A new method is one module (its estimator and model class, the model on the
:class:`~bikeid.ident.linear_model.LinearModel` base), one entry here (a fit function of the
signature of :func:`fit_direct`, a settings dataclass, its model classes and file kinds) and
its tests (``tests/ident/test_methods.py`` runs every entry on the same simulated runs).

Every :class:`Identified` carries the settings it ran (``settings.describe()``), which every
command prints and saves with the model, and whether the data can determine its models:
each fit function first calls :func:`check_informativity` (the settings' ``targets`` count
each model's free parameters; :func:`bikeid.ident.informativity.assess` judges the input's
feedback share and order of excitation) and refuses data that cannot
(:class:`~bikeid.sim.errors.UntrustworthyResult`) unless told ``informativity="report"``
or ``"skip"``, which the result records.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

import numpy as np

from bikeid.dataset.run import Run
from bikeid.ident import greybox, pem
from bikeid.ident.canonical import SPEED_NAMES, THETA_NAMES
from bikeid.ident.direct import MOORE_ROLL, MOORE_STEER, DirectResult, identify, parse_entry
from bikeid.ident.greybox import GreyboxModel
from bikeid.ident.informativity import INFORMATIVITY, SKIPPED_NOTE, guard
from bikeid.ident.linear_model import LinearModel, SpeedDependentModel
from bikeid.ident.pem import CanonicalModel, SpeedCanonicalModel
from bikeid.ident.signals import prepare
from bikeid.ident.tailored_iv import identify_tailored
from bikeid.sim.errors import InputError
from bikeid.sim.linear import canonical_matrices
from bikeid.sim.parameters import BicycleParameters, from_mapping

__all__ = [
    "DIRECT_PRESETS",
    "METHODS",
    "DirectSettings",
    "GreyboxSettings",
    "Identified",
    "Method",
    "ModelCodec",
    "PRESETS",
    "PemSettings",
    "Preset",
    "Resolved",
    "Target",
    "check_informativity",
    "fit_direct",
    "fit_greybox",
    "fit_pem",
    "method",
    "model_codecs",
    "model_kinds",
    "names",
    "resolve",
    "split_free",
]

#: Differences the direct method can form accelerations with (:func:`ident.signals.prepare`).
DERIVATIVES = ("interval", "central", "forward", "backward")
#: Instrument sets of the direct method (None = least squares).
INSTRUMENTS = ("lagged", "dither", "external", "tailored")


def _choice(name: str, value: Any, allowed: Sequence[Any]) -> None:
    if value not in allowed:
        raise InputError(f"{name}={value!r}: choose one of {', '.join(map(str, allowed))}")


@dataclass(frozen=True)
class Target:
    """One model a fit estimates, as the informativity check sees it.

    Attributes
    ----------
    what : str
        The model, for messages (e.g. ``"the canonical PEM model at 4.5 m/s"``).
    runs : tuple of Run
        The runs that model is fitted to.
    n_params : int
        Its free parameters.
    min_speeds : int
        Distinct speeds its excited runs must cover (2 for a model over speed; capped at
        the runs' own distinct speeds by :func:`bikeid.ident.informativity.assess`).
    key : float or int or None
        The speed [m/s] (per-speed models) or run index (per-run models) the record is
        filed under; None for one model over all runs.
    """

    what: str
    runs: tuple[Run, ...]
    n_params: int
    min_speeds: int = 1
    key: float | int | None = None


def _forced(runs: Sequence[Run]) -> bool:
    """Whether some run logs a lateral force (then HdF is free by default)."""
    return any(np.any(r["F"]) for r in runs if "F" in r.signals)


class _Settings:
    """What every method's settings dataclass shares: JSON out, command-line options in."""

    def targets(self, runs: Sequence[Run], free: Sequence[str] | None = None) -> list[Target]:
        """The models a fit with these settings estimates and their free parameters.

        Parameters
        ----------
        runs : sequence of Run
            The runs to be fitted.
        free : sequence of str, optional
            Free matrix entries (methods that take them).

        Returns
        -------
        list of Target
            One per model; the default is one model over all runs with as many free
            parameters as ``free`` names (a method without free entries overrides this).

        Raises
        ------
        InputError
            If the settings cannot count their parameters without ``free``.
        """
        if not free:
            raise InputError(f"{type(self).__name__} does not count its free parameters: give "
                             "free entries or define targets()")  # fmt: skip
        return [Target("the model", tuple(runs), len(free), 2)]

    def to_json(self) -> dict[str, Any]:
        """The settings as plain JSON types.

        Returns
        -------
        dict
            Every field by name.
        """
        return asdict(self)  # type: ignore[call-overload]

    @classmethod
    def from_options(cls, options: Mapping[str, Any]) -> Any:
        """Settings from command-line style options (missing ones keep their defaults).

        Parameters
        ----------
        options : mapping
            May hold any field by name; a None value keeps the field's default.

        Returns
        -------
        settings
            An instance of the class.
        """
        names = [f.name for f in fields(cls)]  # type: ignore[arg-type]
        kw = {n: options[n] for n in names if options.get(n) is not None}
        return cls(**kw)


@dataclass(frozen=True)
class DirectSettings(_Settings):
    """Settings of the direct method, each with its named default.

    Parameters
    ----------
    derivative : {"interval", "central", "forward", "backward"}
        How the accelerations are formed (:func:`bikeid.ident.signals.prepare`):
        ``"interval"`` (default) the equation averaged over each sample interval, exact for
        zero-order-held torques; ``"central"`` Moore & Hubbard's central differences.
    cutoff_hz : float or None
        Zero-phase 2nd-order Butterworth low-pass [Hz] on every signal, 0 = none; None
        (default) means 3 Hz with ``"interval"`` and Moore & Hubbard's 15 Hz otherwise.
    iv : str or None
        Instrumental variables: None (default) is ordinary least squares; ``"lagged"``,
        ``"dither"``, ``"external"`` (:func:`bikeid.ident.direct.identify` instruments) or
        ``"tailored"`` (:func:`bikeid.ident.tailored_iv.identify_tailored`, 3 iterations).
    lags : int
        Instrument lags [samples] (default 1).
    covariance : {"white", "run"}
        Standard-error formula (default ``"white"``, the paper's; ``"run"``
        cluster-robust over runs).
    remove_means : bool
        Subtract each signal's time mean before the regression (default True, Moore &
        Hubbard's; not from v, F).

    Attributes
    ----------
    derivative, cutoff_hz, iv, lags, covariance, remove_means
        As the parameters.
    """

    derivative: str = "interval"
    cutoff_hz: float | None = None
    iv: str | None = None
    lags: int = 1
    covariance: str = "white"
    remove_means: bool = True

    def __post_init__(self) -> None:
        _choice("derivative", self.derivative, DERIVATIVES)
        _choice("iv", self.iv, (None, *INSTRUMENTS))
        _choice("covariance", self.covariance, ("white", "run"))
        if self.cutoff_hz is not None and not (np.isfinite(self.cutoff_hz) and self.cutoff_hz >= 0):
            raise InputError(f"cutoff_hz={self.cutoff_hz}: give a frequency >= 0 [Hz] (0: none)")
        whole = isinstance(self.lags, (int, np.integer)) or (
            isinstance(self.lags, float) and self.lags.is_integer()
        )
        if not whole or self.lags < 1:
            raise InputError(f"lags={self.lags}: give a whole number of samples >= 1")

    @property
    def cutoff(self) -> float:
        """float: the cut-off actually used [Hz] (0 = no filter): ``cutoff_hz``, or its
        default for the derivative (3 Hz interval, 15 Hz otherwise)."""
        if self.cutoff_hz is not None:
            return float(self.cutoff_hz)
        return 3.0 if self.derivative == "interval" else 15.0

    def describe(self) -> str:
        """One line naming every setting that ran.

        Returns
        -------
        str
            E.g. ``"least squares, interval-averaged equation, 3 Hz low-pass"``.
        """
        est = "least squares" if self.iv is None else f"instrumental variables ({self.iv}"
        if self.iv not in (None, "tailored"):
            est += f", {self.lags} lag{'s' * (self.lags != 1)}"
        est += "" if self.iv is None else ")"
        der = {"interval": "interval-averaged equation"}.get(
            self.derivative, f"{self.derivative} differences"
        )
        cut = f"{self.cutoff:g} Hz low-pass" if self.cutoff else "no low-pass"
        se = "" if self.covariance == "white" else ", run-clustered standard errors"
        means = "" if self.remove_means else ", means kept"
        return f"{est}, {der}, {cut}{means}{se}"

    def targets(self, runs: Sequence[Run], free: Sequence[str] | None = None) -> list[Target]:
        """One model over all runs: the free entries of both rows.

        Parameters
        ----------
        runs : sequence of Run
            The runs to be fitted.
        free : sequence of str, optional
            Free entries (default Moore & Hubbard's sets, HdF only when a run logs a
            lateral force, as :func:`bikeid.ident.direct.identify`).

        Returns
        -------
        list of Target
            The one model, needing excited runs at two speeds when the runs span two.
        """
        n = len(free) if free else len(MOORE_ROLL) + len(MOORE_STEER) - (not _forced(runs))
        est = "least-squares" if self.iv is None else "instrumental-variables"
        return [Target(f"the direct {est} model", tuple(runs), n, 2)]

    def to_json(self) -> dict[str, Any]:
        """The settings as plain JSON types, the resolved cut-off included.

        Returns
        -------
        dict
            ``derivative``, ``cutoff`` [Hz] (resolved), ``iv``, ``lags``, ``covariance``,
            ``remove_means``.
        """
        d = super().to_json()
        d["cutoff"] = self.cutoff  # resolved: what ran
        del d["cutoff_hz"]
        return d

    @classmethod
    def from_options(cls, options: Mapping[str, Any]) -> DirectSettings:
        """Settings from command-line style options (missing ones keep their defaults).

        Parameters
        ----------
        options : mapping
            May hold ``derivative``, ``cutoff`` [Hz] (or ``cutoff_hz``), ``iv`` (True =
            lagged instruments, False/None = least squares, or an instrument name),
            ``lags``, ``covariance`` and, by name, ``preset`` (:data:`DIRECT_PRESETS`,
            the base the other options change).

        Returns
        -------
        DirectSettings
            The settings.
        """
        name = options.get("preset") or "default"
        _choice("preset", name, tuple(DIRECT_PRESETS))
        base = DIRECT_PRESETS[name]
        kw: dict[str, Any] = {}
        if options.get("derivative") is not None:
            kw["derivative"] = options["derivative"]
        cut = options.get("cutoff_hz", options.get("cutoff"))
        if cut is not None:
            try:
                kw["cutoff_hz"] = float(cut)
            except (TypeError, ValueError):
                raise InputError(f"cutoff={cut!r}: give a frequency >= 0 [Hz] (0: none)") from None
        iv = options.get("iv")
        if iv is True:
            kw["iv"] = "lagged"
        elif isinstance(iv, str):
            kw["iv"] = iv
        for k in ("lags", "covariance", "remove_means"):
            if options.get(k) is not None:
                kw[k] = options[k]
        return replace(base, **kw)


#: Named direct-method settings: bikeid's default (interval-averaged equation, 3 Hz, least
#: squares), Moore & Hubbard's published processing (central differences of the 15 Hz
#: low-passed rates, least squares; their paper §4) and the testbed's instrumental variables
#: on the dither and roll reference (``bikeid identify accuracy``'s ``direct`` row); and the
#: regression on the logged signals as they are (central differences of the unfiltered
#: rates, means kept: the measured-data study's ``direct`` model).
DIRECT_PRESETS: dict[str, DirectSettings] = {
    "default": DirectSettings(),
    "moore-hubbard": DirectSettings(derivative="central", cutoff_hz=15.0),
    "testbed-iv": DirectSettings(
        derivative="interval", cutoff_hz=3.0, iv="external", lags=40, covariance="run"
    ),
    "unfiltered": DirectSettings(derivative="central", cutoff_hz=0.0, remove_means=False),
}


@dataclass(frozen=True)
class PemSettings(_Settings):
    """Settings of the canonical prediction-error method.

    Parameters
    ----------
    speed_parameterized : bool
        One model over all speeds (a_odd = alpha + beta v^2, a_even = gamma v; needs runs at
        two or more speeds) instead of one model per speed (default False).
    noise_model : {"free", "kalman", "gain", "none"}
        Innovation gain estimated (default "free", consistent in closed loop: the Kalman
        gain of fitted noise covariances, :data:`bikeid.ident.pem.FREE_NOISE_MODEL`),
        "kalman" (the same, named), "gain" (K's entries free; per speed only) or "none"
        (K = 0, output error).

    Attributes
    ----------
    speed_parameterized, noise_model
        As the parameters.
    """

    speed_parameterized: bool = False
    noise_model: str = "free"

    def __post_init__(self) -> None:
        _choice("noise_model", self.noise_model, ("free", "kalman", "gain", "none"))
        if self.speed_parameterized and self.noise_model in ("kalman", "gain"):
            raise InputError(
                f"noise_model={self.noise_model} is a per-speed noise model: a "
                "speed-parameterized model takes noise_model free (its joint Kalman gains) "
                "or none"
            )

    def targets(self, runs: Sequence[Run], free: Sequence[str] | None = None) -> list[Target]:
        """The canonical models: one per speed (10 parameters each), or one over speed.

        Parameters
        ----------
        runs : sequence of Run
            The runs to be fitted.
        free : sequence of str, optional
            Not used (every canonical parameter is free).

        Returns
        -------
        list of Target
            Per speed (``key`` the speed) :data:`~bikeid.ident.canonical.THETA_NAMES`, or
            one model over speed with :data:`~bikeid.ident.canonical.SPEED_NAMES` needing
            excited runs at two speeds.
        """
        if self.speed_parameterized:
            return [Target("the speed-parameterized PEM model", tuple(runs), len(SPEED_NAMES),
                           2)]  # fmt: skip
        return [Target(f"the canonical PEM model at {v:g} m/s",
                       tuple(r for r in runs if round(r.speed, 6) == v), len(THETA_NAMES), 1, v)
                for v in _speeds(runs)]  # fmt: skip

    def describe(self) -> str:
        """One line naming every setting that ran.

        Returns
        -------
        str
            E.g. ``"one canonical model per speed, innovation gain estimated"``.
        """
        what = ("canonical models per speed, then one speed-parameterized model started "
                "from them" if self.speed_parameterized
                else "one canonical model per speed")  # fmt: skip
        from bikeid.ident.pem import FREE_NOISE_MODEL

        kinds = {"kalman": "innovation gain estimated (Kalman gain of fitted noise "
                 "covariances)", "gain": "innovation gain estimated (free entries)",
                 "none": "output error", "joint": "innovation gain estimated (Kalman gains "
                 "of joint noise covariances)"}  # fmt: skip
        noise = self.noise_model
        if noise == "free":  # what "free" fits: per speed pem's choice, over speed joint gains
            noise = "joint" if self.speed_parameterized else FREE_NOISE_MODEL
        k = kinds[noise]
        return f"{what}, {k}"


@dataclass(frozen=True)
class GreyboxSettings(_Settings):
    """Settings of the grey-box prediction-error method.

    Parameters
    ----------
    drop_unidentifiable : bool
        Fix the worst-determined free entries until the condition number is below
        :data:`bikeid.ident.greybox.MAX_CONDITION` (default False: refuse, exit 4).
    mode : {"joint", "per_speed"}
        One fit over all runs (default) or one per run (K2dd then fixed: K0dd and K2dd are
        not separable at one speed).

    Attributes
    ----------
    drop_unidentifiable, mode
        As the parameters.
    """

    drop_unidentifiable: bool = False
    mode: str = "joint"

    def __post_init__(self) -> None:
        _choice("mode", self.mode, ("joint", "per_speed"))

    def targets(self, runs: Sequence[Run], free: Sequence[str] | None = None) -> list[Target]:
        """The grey-box models: one over all runs, or one per run.

        Parameters
        ----------
        runs : sequence of Run
            The runs to be fitted.
        free : sequence of str, optional
            Free entries (default :data:`bikeid.ident.greybox.DEFAULT_FREE`, plus HdF when a
            run logs a lateral force; per run without K2dd, as :func:`fit_greybox`).

        Returns
        -------
        list of Target
            One model needing excited runs at two speeds when the runs span two, or one per
            run (``key`` its index).
        """
        forced = _forced(runs)
        if self.mode == "joint":
            n = len(free) if free else len(greybox.DEFAULT_FREE) + forced
            return [Target("the grey-box model", tuple(runs), n, 2)]
        n = len(free) if free else len(greybox.DEFAULT_FREE) - 1  # fit_greybox: no K2dd, HdF
        return [Target(f"the grey-box model of run {k + 1} ({r.speed:g} m/s)", (r,), n, 1, k)
                for k, r in enumerate(runs)]  # fmt: skip

    def describe(self) -> str:
        """One line naming every setting that ran.

        Returns
        -------
        str
            E.g. ``"one fit over all speeds, innovation gain per speed, refuse an
            ill-conditioned free set"``.
        """
        what = "one fit over all speeds" if self.mode == "joint" else "one fit per run"
        drop = ("fix ill-determined entries" if self.drop_unidentifiable
                else "refuse an ill-conditioned free set")  # fmt: skip
        return f"{what}, innovation gain per speed, {drop}"

    def to_json(self) -> dict[str, Any]:
        """The settings as plain JSON types.

        Returns
        -------
        dict
            ``drop_unidentifiable``, ``mode``, ``noise_model`` (always ``"free"``).
        """
        return {**super().to_json(), "noise_model": "free"}


@dataclass(frozen=True)
class Identified:
    """What a method returns: the models, the settings that ran and a summary.

    Attributes
    ----------
    method : str
        The method's name in :data:`METHODS`.
    settings : DirectSettings, PemSettings or GreyboxSettings
        The settings that ran (``settings.describe()`` names them).
    models : tuple of LinearModel
        The identified models, one per model file (per-speed PEM: one per speed).
    speeds : tuple of float
        Nominal speeds [m/s] of the runs (sorted, distinct, rounded to 1e-6 m/s).
    outputs : tuple of str
        Measured states fitted.
    at_speed : dict of float to LinearModel
        The model that describes each speed (a model over speed, or that speed's model).
    interval_models : dict of float to CanonicalModel or None
        Per speed a canonical model with a parameter covariance (for eigenvalue intervals);
        None where the method gives none (direct).
    speed_model : SpeedCanonicalModel or None
        A speed-parameterized canonical model with covariance (critical-speed intervals).
    details : dict
        Method-specific numbers as JSON types (matrices and free entries with standard
        errors, canonical parameters, condition numbers, torque fits, notes).
    informativity : dict or None
        Whether the data can determine the models (:func:`check_informativity`'s record):
        one model's :meth:`~bikeid.ident.informativity.Informativity.to_json`, or
        ``{"per_speed": {speed: ...}}`` / ``{"per_run": {index: ...}}``; with
        ``informativity="skip"`` ``{"skipped": True, "note": ...}``.  None only for an
        :class:`Identified` built by hand.
    """

    method: str
    settings: Any
    models: tuple[LinearModel, ...]
    speeds: tuple[float, ...]
    outputs: tuple[str, ...]
    at_speed: dict[float, LinearModel]
    interval_models: dict[float, CanonicalModel] | None = None
    speed_model: SpeedCanonicalModel | None = None
    details: dict[str, Any] = field(default_factory=dict)
    informativity: dict[str, Any] | None = None

    def eigenvalues(self, speed: float) -> np.ndarray:
        """Eigenvalues at one of the fitted speeds, ordered and named.

        Parameters
        ----------
        speed : float
            One of :attr:`speeds` [m/s].

        Returns
        -------
        Eigenvalues
            :meth:`bikeid.ident.linear_model.LinearModel.eigenvalues` of the model at that
            speed [1/s].
        """
        m = self.at_speed[round(float(speed), 6)]
        return m.eigenvalues(speed if isinstance(m, SpeedDependentModel) else None)


def _speeds(runs: Sequence[Run]) -> list[float]:
    return sorted({round(r.speed, 6) for r in runs})


def split_free(free: Sequence[str] | None) -> tuple[list[str] | None, list[str] | None]:
    """Free entry names split into the roll row's and the steer row's.

    Parameters
    ----------
    free : sequence of str or None
        Entry names (:func:`bikeid.ident.direct.parse_entry`), or None for the defaults.

    Returns
    -------
    free_roll, free_steer : list of str or None
        The names of each row (None, None for ``free=None``).

    Raises
    ------
    InputError
        If a name is not an entry name.
    """
    if free is None:
        return None, None
    try:
        rows = [parse_entry(n)[1] for n in free]
    except ValueError as exc:
        raise InputError(f"free entries {list(free)}: {exc}") from None
    return ([n for n, r in zip(free, rows, strict=True) if r == 0],
            [n for n, r in zip(free, rows, strict=True) if r == 1])  # fmt: skip


def check_informativity(
    runs: Run | Sequence[Run],
    settings: Any,
    *,
    free: Sequence[str] | None = None,
    input_name: str = "T_delta",
    informativity: str = "refuse",
) -> dict[str, Any]:
    """Whether ``runs`` can determine the models a fit with ``settings`` estimates.

    Every fit function of :data:`METHODS` calls this before it fits: the models and their
    free parameters come from ``settings.targets(runs, free)``, each is assessed by
    :func:`bikeid.ident.informativity.assess` (the input's feedback share and order of
    excitation).

    Parameters
    ----------
    runs : Run or sequence of Run
        The runs to be fitted.
    settings : DirectSettings, PemSettings or GreyboxSettings
        The method's settings (their ``targets`` method counts the free parameters).
    free : sequence of str, optional
        Free matrix entries (direct, greybox).
    input_name : str, optional
        The input signal [N m] (default ``T_delta``).
    informativity : {"refuse", "report", "skip"}, optional
        Refuse data that cannot determine a model (default), only report it, or skip
        the assessment (:data:`~bikeid.ident.informativity.INFORMATIVITY`).

    Returns
    -------
    dict
        The record: one model's assessment
        (:meth:`~bikeid.ident.informativity.Informativity.to_json`), or ``{"per_speed":
        {speed: assessment}}`` for per-speed models and ``{"per_run": {index: assessment}}``
        for per-run ones; with ``"skip"`` ``{"skipped": True, "note":``
        :data:`~bikeid.ident.informativity.SKIPPED_NOTE` ``}``.

    Raises
    ------
    UntrustworthyResult
        With ``"refuse"``: ``the logs cannot determine <model>: <cause and fix>`` for the
        first model the data cannot determine (its speed or run named).
    InputError
        If ``informativity`` is not one of :data:`~bikeid.ident.informativity.INFORMATIVITY`.
    """
    _choice("informativity", informativity, INFORMATIVITY)
    if informativity == "skip":
        return {"skipped": True, "note": SKIPPED_NOTE}
    runs = [runs] if isinstance(runs, Run) else list(runs)
    records: dict[Any, dict[str, Any]] = {}
    for t in settings.targets(runs, free):
        records[t.key], _ = guard(t.runs, t.n_params, what=t.what, informativity=informativity,
                                  input_name=input_name, min_speeds=t.min_speeds)  # fmt: skip
    if list(records) == [None]:
        return records[None]
    first = next(iter(records))
    return {"per_speed" if isinstance(first, float) else "per_run": records}


def _below(informativity: str) -> str:
    """What a fit function asks of the estimator it calls after its own check: a skip is
    passed on (the models' notes record it), otherwise the estimator only reports (its
    notes name a cause it finds, e.g. in a per-speed start of a model over speed)."""
    return "skip" if informativity == "skip" else "report"


def _matrix_details(res: DirectResult | GreyboxModel) -> dict[str, Any]:
    return {"M": res.M, "C1": res.C1, "K0": res.K0, "K2": res.K2, "H": res.H}


def fit_direct(
    runs: Run | Sequence[Run],
    settings: DirectSettings | None = None,
    *,
    reference=None,
    free: Sequence[str] | None = None,
    outputs: Sequence[str] | None = None,
    progress: Callable[[int, int, str], None] | None = None,
    informativity: str = "refuse",
) -> Identified:
    """The direct method: prepare the signals, then least squares or IV of both rows.

    Parameters
    ----------
    runs : Run or sequence of Run
        Raw runs (all four states, ``T_delta`` [N m], ``v`` [m/s]).
    settings : DirectSettings, optional
        Derivative, cut-off and instruments (default :data:`DIRECT_PRESETS` "default").
    reference : BicycleParameters or CanonicalMatrices, optional
        Values of the fixed entries (default the runs' ``meta["parameters"]``).
    free : sequence of str, optional
        Entries to estimate, both rows (default Moore & Hubbard's sets).
    outputs : sequence of str, optional
        Must be all four states if given (the regressors use every state).
    progress : callable, optional
        Not used (one step).

    informativity : {"refuse", "report", "skip"}, optional
        Before the fit, whether the data can determine the model
        (:func:`check_informativity`): refuse when they cannot (default), report it in
        :attr:`Identified.informativity`, or skip the check (recorded there as skipped).
    Returns
    -------
    Identified
        One :class:`~bikeid.ident.direct.DirectResult` over all speeds; ``details`` holds
        the matrices, the free entries with standard errors, condition numbers, Moore's
        VAF of each row's torque and notes.

    Raises
    ------
    InputError
        If ``outputs`` is not all four states or a free name is unknown;
        ValueError / UntrustworthyResult as :func:`bikeid.ident.direct.identify`.
    UntrustworthyResult
        If the data cannot determine the model (:func:`check_informativity`).
    """
    runs = [runs] if isinstance(runs, Run) else list(runs)
    s = settings or DirectSettings()
    if outputs is not None and set(outputs) != {"phi", "delta", "phidot", "deltadot"}:
        raise InputError(
            f"outputs {tuple(outputs)}: direct least squares needs phi, delta, phidot and "
            "deltadot (its regressors use every state and both accelerations)"
        )
    free_roll, free_steer = split_free(free)
    if reference is None and runs and "parameters" not in runs[0].meta:
        raise InputError("runs carry no parameters: give the reference bicycle for the fixed "
                         "entries")  # fmt: skip
    record = check_informativity(runs, s, free=free, informativity=informativity)
    cutoff = s.cutoff or None

    def prep(r: Run) -> Run:
        return prepare(r, cutoff=cutoff, derivative=s.derivative, subtract_mean=s.remove_means)

    if s.iv == "tailored":
        ref = reference if reference is not None else from_mapping(
            runs[0].meta["parameters"], name="run meta")  # fmt: skip
        start = canonical_matrices(ref) if isinstance(ref, BicycleParameters) else ref
        res = identify_tailored(runs, ref, free_roll, free_steer, prepare=prep, start=start,
                                iterations=3, covariance=s.covariance,
                                informativity=_below(informativity))  # fmt: skip
    else:
        res = identify([prep(r) for r in runs], reference, free_roll, free_steer,
                       method="ls" if s.iv is None else "iv", instruments=s.iv or "lagged",
                       lags=s.lags, covariance=s.covariance,
                       informativity=_below(informativity))  # fmt: skip
    speeds = _speeds(runs)
    details = {
        **_matrix_details(res),
        "free": {k: {"value": v, "stderr": res.stderr[k]} for k, v in res.free.items()},
        "condition": res.condition, "vaf_moore": res.vaf_moore,
        "vaf_variance": res.vaf_variance, "notes": list(res.notes),
    }  # fmt: skip
    if len(speeds) >= 2:
        details["critical_speeds"] = res.critical_speeds()
    return Identified(
        method="direct", settings=s, models=(res,), speeds=tuple(speeds),
        outputs=("phi", "delta", "phidot", "deltadot"), at_speed=dict.fromkeys(speeds, res),
        details=details, informativity=record,
    )  # fmt: skip


def fit_pem(
    runs: Run | Sequence[Run],
    settings: PemSettings | None = None,
    *,
    reference=None,
    free: Sequence[str] | None = None,
    outputs: Sequence[str] | None = None,
    progress: Callable[[int, int, str], None] | None = None,
    informativity: str = "refuse",
) -> Identified:
    """Canonical PEM per speed (each started from the next lower speed's model), and with
    ``speed_parameterized`` one model over all speeds started from them.

    Parameters
    ----------
    runs : Run or sequence of Run
        Runs at one or more nominal speeds.
    settings : PemSettings, optional
        Per speed or speed-parameterized; noise model.
    reference : optional
        Not used (the canonical model has no fixed entries).
    free : sequence of str, optional
        Must be None (every canonical parameter is free).
    outputs : sequence of str, optional
        Measured states fitted (default :data:`bikeid.ident.pem.DEFAULT_OUTPUTS`).
    progress : callable, optional
        ``progress(done, total, label)`` before each fit.

    informativity : {"refuse", "report", "skip"}, optional
        Before the fit, whether the data can determine the model
        (:func:`check_informativity`): refuse when they cannot (default), report it in
        :attr:`Identified.informativity`, or skip the check (recorded there as skipped).
    Returns
    -------
    Identified
        Per-speed :class:`~bikeid.ident.pem.CanonicalModel` (one file each), or one
        :class:`~bikeid.ident.pem.SpeedCanonicalModel`; ``details`` the parameters and
        standard errors (and critical speeds of a model over speed).

    Raises
    ------
    InputError
        If ``free`` is given, or ``speed_parameterized`` with runs at one speed only.
    UntrustworthyResult
        If the data cannot determine a model (:func:`check_informativity`), naming its
        speed.
    """
    runs = [runs] if isinstance(runs, Run) else list(runs)
    s = settings or PemSettings()
    if free:
        raise InputError("free entries apply to the greybox and direct methods (every "
                         "canonical parameter of pem is free)")  # fmt: skip
    speeds = _speeds(runs)
    if s.speed_parameterized and len(speeds) < 2:
        raise InputError(
            "a speed-parameterized model needs runs at two or more speeds to separate alpha "
            f"from beta v^2; the data hold speed {speeds[0] if speeds else '-'} m/s only"
        )
    record = check_informativity(runs, s, informativity=informativity)
    kw: dict[str, Any] = {"noise_model": s.noise_model, "informativity": _below(informativity)}
    if outputs:
        kw["outputs"] = tuple(outputs)
    steps = len(speeds) + bool(s.speed_parameterized)
    per: dict[float, CanonicalModel] = {}
    prev = None
    for k, v in enumerate(speeds):
        if progress:
            progress(k, steps, f"PEM at {v:g} m/s")
        at_v = [r for r in runs if round(r.speed, 6) == v]
        prev = per[v] = pem.fit(at_v, starts=() if prev is None else (prev.theta,), **kw)
    out_names = next(iter(per.values())).outputs
    if s.speed_parameterized:
        if progress:
            progress(len(speeds), steps, "speed-parameterized model")
        model = pem.fit_speed_model(runs, per_speed=per, **kw)
        details = {
            "params": dict(zip(SPEED_NAMES, model.params, strict=True)),
            "stderr": model.stderr,
            "critical_speeds": model.critical_speeds(),
        }
        result = Identified(
            method="pem", settings=s, models=(model,), speeds=tuple(speeds),
            outputs=out_names, at_speed=dict.fromkeys(speeds, model),
            interval_models={v: model.at(v) for v in speeds}, speed_model=model,
            details=details, informativity=record,
        )  # fmt: skip
    else:
        details = {"models": {v: {"theta": m.params, "stderr": m.stderr, "A": m.A, "B": m.B}
                              for v, m in per.items()}}  # fmt: skip
        result = Identified(
            method="pem", settings=s, models=tuple(per.values()), speeds=tuple(speeds),
            outputs=out_names, at_speed=dict(per), interval_models=dict(per), details=details,
            informativity=record,
        )  # fmt: skip
    if progress:
        progress(steps, steps, "done")
    return result


def fit_greybox(
    runs: Run | Sequence[Run],
    settings: GreyboxSettings | None = None,
    *,
    reference=None,
    free: Sequence[str] | None = None,
    outputs: Sequence[str] | None = None,
    progress: Callable[[int, int, str], None] | None = None,
    informativity: str = "refuse",
) -> Identified:
    """Grey-box PEM of the free matrix entries, one fit over all speeds (or one per run).

    Parameters
    ----------
    runs : Run or sequence of Run
        Runs at one or more speeds.
    settings : GreyboxSettings, optional
        Joint or per run; whether ill-determined entries are fixed or refused.
    reference : BicycleParameters or CanonicalMatrices, optional
        Values of the fixed entries and the start (default the runs' meta).
    free : sequence of str, optional
        Entries to estimate (default :data:`bikeid.ident.greybox.DEFAULT_FREE`; per run
        without K2dd).
    outputs : sequence of str, optional
        Measured states fitted.
    progress : callable, optional
        ``progress(done, total, label)`` before each fit.

    informativity : {"refuse", "report", "skip"}, optional
        Before the fit, whether the data can determine the model
        (:func:`check_informativity`): refuse when they cannot (default), report it in
        :attr:`Identified.informativity`, or skip the check (recorded there as skipped).
    Returns
    -------
    Identified
        :class:`~bikeid.ident.greybox.GreyboxModel` (one, or one per run); ``details`` the
        matrices, free entries with standard errors and inflation, condition number, the
        least-determined entries, dropped entries, notes (and critical speeds over 2+
        speeds).

    Raises
    ------
    ValueError, UntrustworthyResult
        As :func:`bikeid.ident.greybox.fit`; UntrustworthyResult also if the data cannot
        determine the model (:func:`check_informativity`).
    """
    runs = [runs] if isinstance(runs, Run) else list(runs)
    s = settings or GreyboxSettings()
    kw: dict[str, Any] = {"drop_unidentifiable": s.drop_unidentifiable,
                          "informativity": _below(informativity)}  # fmt: skip
    if outputs:
        kw["outputs"] = tuple(outputs)
    speeds = _speeds(runs)
    if s.mode == "joint":
        groups = [runs]
    else:
        groups = [[r] for r in runs]
        if free is None:
            free = tuple(n for n in greybox.DEFAULT_FREE if n != "K2dd")
    record = check_informativity(runs, s, free=free, informativity=informativity)
    fits = []
    for k, group in enumerate(groups):
        if progress:
            progress(k, len(groups), f"grey-box fit {k + 1} of {len(groups)}")
        fits.append(greybox.fit(group, list(free) if free else None, reference, **kw))
    res = fits[-1]
    details = {
        **_matrix_details(res), "condition": max(f.condition for f in fits),
        "free": {k: {"value": v, "stderr": res.stderr[k], "inflation": res.inflation[k]}
                 for k, v in res.free.items()},
        "least_determined": list(res.least_determined), "dropped": list(res.dropped),
        "notes": list(res.notes),
    }  # fmt: skip
    at = {round(r.speed, 6): f for f, g in zip(fits, groups, strict=True) for r in g}
    speed_model = None
    if s.mode == "joint" and len(speeds) >= 2:
        details["critical_speeds"] = res.critical_speeds()
        speed_model = res.speed_model()
    if progress:
        progress(len(groups), len(groups), "done")
    return Identified(
        method="greybox", settings=s, models=tuple(fits), speeds=tuple(speeds),
        outputs=tuple(res.outputs), at_speed=at,
        interval_models={v: at[v].at(v) for v in speeds}, speed_model=speed_model,
        details=details, informativity=record,
    )  # fmt: skip


@dataclass(frozen=True)
class ModelCodec:
    """How a method's own model class is written to and read from a model file, for a method
    added after the built-in ones (the built-in kinds are written by
    :mod:`bikeid.ident.model_file` itself), so that adding a method never edits that module.

    Attributes
    ----------
    write : callable
        ``write(model) -> dict``: the file's ``model`` section (plain JSON values).
    read : callable
        ``read(section) -> model``: the model back from that section; raises ``ValueError``,
        ``TypeError`` or ``KeyError`` naming the bad field, which the loader reports as a
        one-line refusal naming the file.
    summary : callable
        ``summary(model) -> dict`` with the file's top-level ``inputs``, ``outputs``,
        ``sample_time`` [s] (or None) and ``speeds`` [m/s] (or None).
    """

    write: Callable[[Any], dict]
    read: Callable[[Mapping[str, Any]], Any]
    summary: Callable[[Any], dict]


@dataclass(frozen=True)
class Method:
    """One identification method of the table.

    Attributes
    ----------
    name : str
        The name used everywhere (``--method``, model files, reports).
    description : str
        One line: what the method estimates.
    fit : callable
        ``fit(runs, settings=None, *, reference=None, free=None, outputs=None,
        progress=None, informativity="refuse") -> Identified``; it checks that the data can
        determine the model before fitting (:func:`check_informativity`, the free
        parameters counted by ``settings.targets``).
    settings_type : type
        The frozen settings dataclass (``describe()``, ``to_json()``,
        ``from_options(mapping)``).
    model_classes : tuple of type
        Classes of the models it returns.
    kinds : tuple of str
        Model-file kind of each class, in the same order (:mod:`bikeid.ident.model_file`).
    fixed_entries : bool
        Whether it needs the values of fixed matrix entries (a reference bicycle).
    free_entries : bool
        Whether ``free`` (matrix entries to estimate) applies.
    codecs : mapping of str to ModelCodec
        Model-file codec per kind, for kinds the model file does not write itself (a new
        method's); empty for the built-in methods.
    """

    name: str
    description: str
    fit: Callable[..., Identified]
    settings_type: type
    model_classes: tuple[type, ...]
    kinds: tuple[str, ...]
    fixed_entries: bool
    free_entries: bool
    codecs: Mapping[str, ModelCodec] = field(default_factory=dict)

    def settings(self, options: Mapping[str, Any] | None = None) -> Any:
        """The method's settings from options (missing ones at their defaults).

        Parameters
        ----------
        options : mapping, optional
            Options by name (``settings_type.from_options``).

        Returns
        -------
        DirectSettings, PemSettings or GreyboxSettings
            The settings value.
        """
        return self.settings_type.from_options(dict(options or {}))

    def one_file_per_speed(self, settings: Any) -> bool:
        """Whether the method writes one model file per speed with these settings.

        Parameters
        ----------
        settings : DirectSettings, PemSettings or GreyboxSettings
            The settings.

        Returns
        -------
        bool
            True for per-speed PEM.
        """
        return self.name == "pem" and not settings.speed_parameterized


#: Every identification method by name.
METHODS: dict[str, Method] = {
    "pem": Method(
        "pem", "canonical prediction-error model per speed or over speed (Chen & Dao)",
        fit_pem, PemSettings, (CanonicalModel, SpeedCanonicalModel),
        ("canonical-pem", "speed-canonical-pem"), fixed_entries=False, free_entries=False,
    ),
    "greybox": Method(
        "greybox", "prediction-error fit of chosen entries of M, C1, K0, K2 over all speeds",
        fit_greybox, GreyboxSettings, (GreyboxModel,), ("greybox",), fixed_entries=True,
        free_entries=True,
    ),
    "direct": Method(
        "direct", "least squares or IV of the equations of motion (Moore & Hubbard)",
        fit_direct, DirectSettings, (DirectResult,), ("direct",), fixed_entries=True,
        free_entries=True,
    ),
}  # fmt: skip


def model_codecs() -> dict[str, ModelCodec]:
    """Model-file codecs of the methods that bring their own (:attr:`Method.codecs`).

    Returns
    -------
    dict of str to ModelCodec
        Kind -> codec.
    """
    return {k: c for m in METHODS.values() for k, c in m.codecs.items()}


def method(name: str) -> Method:
    """The table entry of a method name.

    Parameters
    ----------
    name : str
        A key of :data:`METHODS`.

    Returns
    -------
    Method
        Its entry.

    Raises
    ------
    InputError
        Naming the known methods, if ``name`` is not one.
    """
    if name not in METHODS:
        raise InputError(f"method {name!r}: choose one of {', '.join(METHODS)}")
    return METHODS[name]


def model_kinds() -> dict[str, type]:
    """Model-file kind -> model class of every method (what the model loader reads).

    Returns
    -------
    dict of str to type
        E.g. ``{"canonical-pem": CanonicalModel, ..., "direct": DirectResult}``.
    """
    return {k: c for m in METHODS.values() for k, c in zip(m.kinds, m.model_classes, strict=True)}


@dataclass(frozen=True)
class Preset:
    """A named setting of a method of the table, usable wherever a method name is.

    Attributes
    ----------
    name : str
        The preset's name (``bikeid identify accuracy`` row, consistency study estimator).
    method : str
        The :data:`METHODS` entry it runs.
    options : mapping
        Settings options (``Method.settings``), e.g. ``{"preset": "moore-hubbard"}``.
    description : str
        One line: what the preset estimates.
    """

    name: str
    method: str
    options: Mapping[str, Any]
    description: str


#: Named presets of the table's methods.  ``direct_ls`` is Moore & Hubbard's own estimator
#: as published (ordinary least squares, central differences of the 15 Hz low-passed rates,
#: :data:`DIRECT_PRESETS` ``"moore-hubbard"``): the accuracy table's row beside its IV
#: ``direct``.
PRESETS: dict[str, Preset] = {
    "direct_ls": Preset(
        "direct_ls", "direct", {"preset": "moore-hubbard"},
        "Moore & Hubbard's least squares as published (central differences, 15 Hz)",
    ),
}  # fmt: skip


def names() -> tuple[str, ...]:
    """Every name the table answers to: each method followed by its presets.

    Returns
    -------
    tuple of str
        :data:`METHODS` keys in table order, each followed by the :data:`PRESETS` of that
        method (e.g. ``("pem", "greybox", "direct", "direct_ls")``); read at call time, so
        an entry added to either table appears in every list built from it.
    """
    out: list[str] = []
    for m in METHODS:
        out.append(m)
        out += [k for k, p in PRESETS.items() if p.method == m]
    return tuple(out)


@dataclass(frozen=True)
class Resolved:
    """A method name or preset with its settings, ready to fit.

    Attributes
    ----------
    label : str
        The text it was resolved from (``"pem:noise_model=none"``), the name in reports.
    method : Method
        The table entry.
    settings : DirectSettings, PemSettings or GreyboxSettings
        The settings (preset options, then the text's overrides).
    """

    label: str
    method: Method
    settings: Any

    def fit(self, runs: Sequence[Run], **kw: Any) -> Identified:
        """``method.fit(runs, settings, **kw)``.

        Parameters
        ----------
        runs : sequence of Run
            The runs.
        **kw
            Keyword arguments of :attr:`Method.fit` (``reference``, ``free``, ...).

        Returns
        -------
        Identified
            The fit.
        """
        return self.method.fit(list(runs), self.settings, **kw)


def _value(text: str) -> Any:
    low = text.strip().lower()
    if low in ("true", "false"):
        return low == "true"
    if low == "null":
        return None
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text.strip()


def resolve(spec: str) -> Resolved:
    """A method from its name, a preset, or either with settings: ``NAME[:KEY=VALUE]...``.

    Parameters
    ----------
    spec : str
        E.g. ``"pem"``, ``"direct_ls"``, ``"pem:noise_model=none"``,
        ``"direct:iv=lagged:lags=2"``.  Values ``true``/``false`` are booleans, ``null``
        is None (``iv=null``: least squares), numbers are numbers, anything else a string.

    Returns
    -------
    Resolved
        The method and its settings (checked by the settings dataclass).

    Raises
    ------
    InputError
        Naming the known names if the name is unknown, the method's settings if a key is
        not one, or the bad value.
    """
    name, *pairs = str(spec).strip().split(":")
    if name in PRESETS:
        preset = PRESETS[name]
        base, options = method(preset.method), dict(preset.options)
    elif name in METHODS:
        base, options = METHODS[name], {}
    else:
        raise InputError(f"method {name!r}: choose one of {', '.join(names())} "
                         "(settings as NAME:KEY=VALUE, e.g. pem:noise_model=none)")  # fmt: skip
    keys = [f.name for f in fields(base.settings_type)]
    for pair in pairs:
        key, eq, val = pair.partition("=")
        key = key.strip()
        if not eq or key not in keys:
            raise InputError(f"{spec!r}: {pair!r} is not KEY=VALUE with KEY one of "
                             f"{', '.join(keys)} (settings of {base.name})")  # fmt: skip
        options[key] = _value(val)
    try:
        settings = base.settings(options)
    except TypeError as exc:  # a value of the wrong kind for the dataclass
        raise InputError(f"{spec!r}: {exc}") from None
    return Resolved(str(spec).strip(), base, settings)
