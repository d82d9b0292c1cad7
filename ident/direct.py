"""Moore & Hubbard direct identification: least squares on the canonical equations.

Model (Moore & Hubbard eq. 1, Meijaard notation; q = [phi, delta])::

    M q'' + v C1 q' + (g K0 + v^2 K2) q = [T_phi, T_delta] + H F

Each row (roll ``p``, steer ``d``) is a linear regression Gamma Theta = Y
(eqs. 2-5): Theta holds the free entries, every fixed entry is moved to the
right-hand side.  Entry names are the matrix and the row/column letters,
``p`` = phi, ``d`` = delta: ``Mpd`` = M[phi, delta], ``C1dp``, ``K0dd``, ``K2pd``,
``HpF``, ``HdF``.  Regressor of entry X_rc: M -> q''_c, C1 -> v q'_c, K0 -> g q_c,
K2 -> v^2 q_c, H_rF -> -F.  The speed v is the instantaneous per-sample speed
(what separates K0 from K2; reference T3).

Two-stage with symmetry (``symmetric=True``, the paper's procedure): solve the roll
row, then set Mdp := Mpd and K0dp := K0pd and solve the steer row.  Parameter
covariance sigma^2 (Gamma' Gamma)^-1 with sigma^2 = SSE / (N - d) (paper's eqs.
``eqVariance``/``eqCovariance``); the steer row's standard errors treat the values
taken from the roll row as exact.  That formula assumes white equation errors; after a
low-pass filter they are strongly coloured and it understates the spread several-fold.
``covariance="run"`` gives the cluster-robust sandwich instead, runs as independent clusters
(residuals correlated within a run, independent between runs):
B^-1 [sum_i W_i' e_i e_i' W_i] B^-T with B = W' Gamma, W = Gamma (LS) or the fitted
instruments (IV), e_i the residuals of run i; it needs several runs (>= 2 d advisable).

``method="iv"`` replaces least squares by instrumental variables (two-stage least
squares) against the closed-loop bias of an unmeasured torque disturbance, which
enters q'' and through the loop every regressor (reference F5, F6, T5):
``instruments="lagged"`` uses the regressors ``lags`` samples earlier (valid when the
equation error is white); ``instruments="dither"`` uses the logged dither and its
lags 0..``lags``, each times 1, v and v^2 (valid for any disturbance independent of
the dither); ``instruments="external"`` uses both external signals of the loop, the
dither and the roll reference, at lags 0..``lags`` in about 20 steps, each times 1, v and
v^2 (valid when the sensor noise and disturbances are independent of both; suited to
long-memory closed-loop responses such as a chirp-driven loop, where a few dither lags
explain little of the regressors); ``instruments="simulated"`` takes the regressors of
``instrument_runs``, noise-free runs simulated from the external signals alone through a
model of the closed loop (Ljung's "tailor-made" instruments: one instrument per free entry,
so no overfitting of the sensor noise however coloured it is; built and iterated by
:func:`ident.tailored_iv.identify_tailored`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from bikeid.dataset.run import Run
from bikeid.ident.informativity import guard
from bikeid.ident.linear_model import SpeedDependentModel
from bikeid.ident.signals import check_sampling, differentiate
from bikeid.sim.errors import UntrustworthyResult
from bikeid.sim.linear import CanonicalMatrices, canonical_matrices, state_matrices
from bikeid.sim.parameters import BicycleParameters, from_mapping

__all__ = [
    "MOORE_ROLL",
    "MOORE_STEER",
    "ALL_ENTRIES",
    "DirectResult",
    "identify",
    "parse_entry",
    "regressors",
    "vaf_moore",
    "vaf_variance",
]

#: The free sets of Moore & Hubbard (paper §5.2; ``scripts/fit_benchmark_canon.py``).
MOORE_ROLL = ("Mpd", "C1pd", "K0pd")
MOORE_STEER = ("Mdd", "C1dp", "C1dd", "K0dd", "K2dd", "HdF")

_MATS = ("M", "C1", "K0", "K2")
_IDX = {"p": 0, "d": 1}
ALL_ENTRIES = tuple(m + r + c for m in _MATS for r in "pd" for c in "pd") + ("HpF", "HdF")


def vaf_moore(measured: np.ndarray, predicted: np.ndarray) -> float:
    """Moore's eq. 6: 1 - ||predicted - measured|| / ||measured - mean(measured)||.

    A norm ratio (= MATLAB ``compare``'s NRMSE fit), *not* the variance ratio; NaN when
    the measured signal is constant.

    Parameters
    ----------
    measured : (N,) array_like
        Measured signal, any unit.
    predicted : (N,) array_like
        Predicted signal, same unit and samples as ``measured``.

    Returns
    -------
    float
        The fit, dimensionless; 1 for a perfect prediction, <= 1, negative when the
        prediction is worse than the mean.  NaN when ``measured`` is constant.
    """
    y, yp = np.asarray(measured, float), np.asarray(predicted, float)
    den = np.linalg.norm(y - y.mean())
    return float(1.0 - np.linalg.norm(yp - y) / den) if den > 0 else float("nan")


def vaf_variance(measured: np.ndarray, predicted: np.ndarray) -> float:
    """Variance accounted for, 1 - var(measured - predicted) / var(measured).

    For a zero-mean error, vaf_variance = 1 - (1 - vaf_moore)^2 (reference T11).

    Parameters
    ----------
    measured : (N,) array_like
        Measured signal, any unit.
    predicted : (N,) array_like
        Predicted signal, same unit and samples as ``measured``.

    Returns
    -------
    float
        The variance ratio, dimensionless, <= 1 (a constant offset of the error is not
        penalised).  NaN when ``measured`` is constant.
    """
    y, yp = np.asarray(measured, float), np.asarray(predicted, float)
    den = np.var(y)
    return float(1.0 - np.var(y - yp) / den) if den > 0 else float("nan")


def parse_entry(name: str) -> tuple[str, int, int | None]:
    """Matrix, row and column of an entry name (``"Mpd"`` -> ``("M", 0, 1)``).

    Parameters
    ----------
    name : str
        Entry name as in the module docstring: a matrix (``M``, ``C1``, ``K0``, ``K2``)
        followed by the row and column letters (``p`` = phi, ``d`` = delta), or ``HpF`` /
        ``HdF`` for the lateral-force column.

    Returns
    -------
    matrix : str
        ``"M"``, ``"C1"``, ``"K0"``, ``"K2"`` or ``"H"``.
    row : int
        0 (roll equation) or 1 (steer equation).
    column : int or None
        0 (phi) or 1 (delta); None for ``H``.

    Raises
    ------
    ValueError
        If ``name`` is not one of :data:`ALL_ENTRIES`.
    """
    if name in ("HpF", "HdF"):
        return "H", _IDX[name[1]], None
    for m in _MATS:
        if name.startswith(m) and len(name) == len(m) + 2 and set(name[len(m) :]) <= set("pd"):
            return m, _IDX[name[len(m)]], _IDX[name[len(m) + 1]]
    raise ValueError(f"unknown matrix entry {name!r}; valid names are {list(ALL_ENTRIES)}")


def _data(run: Run, source: str, derivative: str) -> dict[str, np.ndarray]:
    sig = run.signals if source == "signals" else run.truth
    if sig is None:
        raise ValueError("this run has no noise-free signals; use source='signals'")
    get = (lambda k: run[k]) if source == "signals" else run.true
    d = {k: np.asarray(get(k), float) for k in ("phi", "delta", "phidot", "deltadot", "v")}
    for k in ("T_phi", "T_delta", "F"):
        d[k] = np.asarray(get(k), float)
    for acc, rate in (("phiddot", "phidot"), ("deltaddot", "deltadot")):
        d[acc] = sig[acc] if acc in sig else differentiate(d[rate], run.dt, derivative)
    return d


def regressors(d: dict[str, np.ndarray], g: float) -> dict[str, np.ndarray]:
    """Regressor column of every entry name (see module docstring) from one run's data.

    Parameters
    ----------
    d : dict of str to (N,) ndarray
        One run's samples: ``phi``, ``delta`` [rad], ``phidot``, ``deltadot`` [rad/s],
        ``phiddot``, ``deltaddot`` [rad/s^2], ``v`` [m/s] (per sample) and ``F`` [N].
    g : float
        Gravitational acceleration [m/s^2].

    Returns
    -------
    dict of str to (N,) ndarray
        For each name of ``ALL_ENTRIES`` (``Mpp`` ... ``K2dd``, ``HpF``, ``HdF``) its
        regressor: M_rc -> q''_c [rad/s^2], C1_rc -> v q'_c [m rad/s^2], K0_rc -> g q_c
        [m rad/s^2], K2_rc -> v^2 q_c [m^2 rad/s^2], H_rF -> -F [N]; the column times the
        entry is a torque [N m] on the left-hand side of row r.
    """
    q = (d["phi"], d["delta"])
    qd = (d["phidot"], d["deltadot"])
    qdd = (d["phiddot"], d["deltaddot"])
    v = d["v"]
    out = {}
    for name in ALL_ENTRIES:
        m, _, c = parse_entry(name)
        out[name] = {
            "M": lambda c=c: qdd[c],
            "C1": lambda c=c: v * qd[c],
            "K0": lambda c=c: g * q[c],
            "K2": lambda c=c: v**2 * q[c],
            "H": lambda: -d["F"],
        }[m]()
    return out


@dataclass(frozen=True)
class DirectResult(SpeedDependentModel):
    """Identified canonical matrices with the statistics of the fit.

    ``M, C1, K0, K2`` (2x2, rows/cols [phi, delta]), ``H`` (2,) [m], gravity ``g``:
    free entries estimated, the others at their fixed values.  ``free`` maps each
    estimated entry to its value, ``stderr`` to its standard error; ``covariance[row]``
    = (names, matrix) per row.  ``condition[row]`` is the condition number of the
    column-scaled regressor matrix; ``vaf_moore``/``vaf_variance`` are the input-side
    (torque) fits per row (NaN when the row's measured torque T + H F is zero).

    Attributes
    ----------
    M : (2, 2) ndarray
        Mass matrix [kg m^2], rows/columns [phi, delta].
    C1 : (2, 2) ndarray
        Velocity-dependent damping-like matrix [kg m]; ``v C1`` is in N m s/rad.
    K0 : (2, 2) ndarray
        Gravity-dependent stiffness matrix [kg m]; ``g K0`` is in N m/rad.
    K2 : (2, 2) ndarray
        Velocity-dependent stiffness matrix [kg]; ``v^2 K2`` is in N m/rad.
    H : (2,) ndarray
        Lateral-force column [HpF, HdF] [m]: torque [N m] per newton of F on the roll and
        steer equations.
    g : float
        Gravitational acceleration [m/s^2] the K0 values refer to.
    free : dict of str to float
        Estimated entries (names as in the module docstring) and their values, in the
        units of their matrix.
    stderr : dict of str to float
        Standard error of each estimated entry, same units.
    covariance : dict of str to (tuple of str, (d, d) ndarray)
        Per row ``"roll"``/``"steer"``: the free names and their covariance matrix
        (``"white"`` or cluster-robust ``"run"`` formula, see :func:`identify`).
    condition : dict of str to float
        Per row: condition number of the column-scaled regressor matrix (dimensionless).
    vaf_moore : dict of str to float
        Per row: Moore's eq. 6 fit of the measured torque T + H F (dimensionless).
    vaf_variance : dict of str to float
        Per row: variance accounted for of the same torque (dimensionless).
    n_samples : int
        Number of samples stacked per row (after any IV lag cut).
    method : str
        ``"ls"``, ``"iv (<instruments>, lags=<n>)"``, ``"iv (simulated)"``, or
        ``"iv (tailor-made)"`` from :func:`ident.tailored_iv.identify_tailored`.
    notes : tuple of str
        Remarks on the fit, e.g. why HdF was not estimated.
    """

    M: np.ndarray
    C1: np.ndarray
    K0: np.ndarray
    K2: np.ndarray
    H: np.ndarray
    g: float
    free: dict[str, float]
    stderr: dict[str, float]
    covariance: dict[str, tuple[tuple[str, ...], np.ndarray]]
    condition: dict[str, float]
    vaf_moore: dict[str, float]
    vaf_variance: dict[str, float]
    n_samples: int
    method: str
    notes: tuple[str, ...] = field(default_factory=tuple)

    def canonical(self) -> CanonicalMatrices:
        """The identified matrices as a :class:`bikeid.sim.linear.CanonicalMatrices`.

        Returns
        -------
        CanonicalMatrices
            ``M, C1, K0, K2, g`` of this result (``H`` is not part of it).
        """
        return CanonicalMatrices(M=self.M, C1=self.C1, K0=self.K0, K2=self.K2, g=self.g)

    #: Inputs of :meth:`state_space` by default: roll and steer torque, lateral force.
    INPUTS = ("T_phi", "T_delta", "F")

    def _matrices_at(self, speed: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        A, B = state_matrices(self.canonical(), speed)
        Bf = np.concatenate([np.zeros(2), np.linalg.solve(self.M, self.H)])
        return A, {"T_phi": B[:, 0], "T_delta": B[:, 1], "F": Bf}

    def _speed_matrices(self) -> CanonicalMatrices:
        return self.canonical()

    def entry(self, name: str) -> float:
        """Value of one matrix entry by name.

        Parameters
        ----------
        name : str
            Entry name as in the module docstring, e.g. ``"Mpd"``, ``"K2dd"``, ``"HdF"``.

        Returns
        -------
        float
            The entry in its matrix's units (M kg m^2, C1 kg m, K0 kg m, K2 kg, H m).

        Raises
        ------
        ValueError
            If ``name`` is not a valid entry name.
        """
        m, r, c = parse_entry(name)
        return float(self.H[r] if m == "H" else getattr(self, m)[r, c])


def _reference_values(reference, H) -> tuple[dict[str, float], float]:
    if isinstance(reference, BicycleParameters):
        cm = canonical_matrices(reference)
    elif isinstance(reference, CanonicalMatrices):
        cm = reference
    else:
        raise ValueError(
            "reference must be BicycleParameters or CanonicalMatrices (the values of the fixed "
            "entries); pass reference=... or use runs with meta['parameters']"
        )
    vals = {}
    for name in ALL_ENTRIES:
        m, r, c = parse_entry(name)
        vals[name] = 0.0 if m == "H" else float(getattr(cm, m)[r, c])
    if H is not None:
        vals["HpF"], vals["HdF"] = (float(h) for h in H)
    return vals, cm.g


def _condition(G: np.ndarray) -> tuple[float, np.ndarray]:
    norms = np.linalg.norm(G, axis=0)
    if np.any(norms == 0):
        null = (norms == 0).astype(float)
        return float("inf"), null / np.linalg.norm(null)
    R = np.linalg.qr(G / norms, mode="r")
    _, s, Vt = np.linalg.svd(R)
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    return cond, Vt[-1]


def _solve_row(
    row, names, G, Y, Z, max_condition, hints, clusters=None
) -> tuple[np.ndarray, np.ndarray, float]:
    cond, null = _condition(G)
    if not np.isfinite(cond) or cond > max_condition:
        involved = [n for n, c in zip(names, null, strict=True) if abs(c) > 0.1]
        hint = "".join(h for key, h in hints if len(set(key) & set(involved)) >= 2)
        raise UntrustworthyResult(
            f"{row} row is unidentifiable: condition number {cond:.3g} of the column-scaled "
            f"regressor matrix exceeds {max_condition:g}; free entries {involved} are "
            f"(nearly) collinear.{hint} Fix one of them at a known value (reference/fixed=) "
            "or add excitation that separates them."
        )
    N, d = G.shape
    if Z is None:
        theta, *_ = np.linalg.lstsq(G, Y, rcond=None)
        Gh = G
    else:
        if Z.shape[1] < d:
            raise ValueError(f"{Z.shape[1]} instruments for {d} free entries: need at least {d}")
        coef, *_ = np.linalg.lstsq(Z, G, rcond=None)
        Gh = Z @ coef
        theta = np.linalg.solve(Gh.T @ G, Gh.T @ Y)
    res = Y - G @ theta
    if clusters is None:
        sigma2 = float(res @ res) / max(N - d, 1)
        cov = sigma2 * np.linalg.inv(Gh.T @ Gh)
    else:
        Binv = np.linalg.inv(Gh.T @ G)
        scores = np.array([Gh[a:b].T @ res[a:b] for a, b in clusters])
        ncl = len(clusters)
        cov = Binv @ (scores.T @ scores) @ Binv.T * ncl / max(ncl - 1, 1)
    return theta, cov, cond


def identify(
    runs: Run | Sequence[Run],
    reference: BicycleParameters | CanonicalMatrices | None = None,
    free_roll: Sequence[str] | None = None,
    free_steer: Sequence[str] | None = None,
    *,
    fixed: dict[str, float] | None = None,
    H: tuple[float, float] | None = None,
    symmetric: bool = True,
    method: str = "ls",
    instruments: str = "lagged",
    lags: int = 1,
    source: str = "signals",
    derivative: str = "central",
    max_condition: float = 1e10,
    instrument_runs: Sequence[Run] | None = None,
    covariance: str = "white",
    informativity: str = "refuse",
) -> DirectResult:
    """Direct least-squares (or IV) identification of M, C1, K0, K2, H from runs.

    Each row of ``M q'' + v C1 q' + (g K0 + v^2 K2) q = [T_phi, T_delta] + H F`` is
    solved as the regression of the module docstring (Moore & Hubbard eqs. 2-5), roll
    row first.

    Parameters
    ----------
    runs : Run or sequence of Run
        One or more runs, stacked row-wise.  Signals used: ``phi``, ``delta`` [rad],
        ``phidot``, ``deltadot`` [rad/s], ``v`` [m/s, per sample], ``T_phi``,
        ``T_delta`` [N m, positive to the right] and ``F`` [N].  Accelerations are taken
        from the signals ``phiddot``/``deltaddot`` [rad/s^2] when present (e.g.
        ``ident.signals.prepare`` or simulator truth), else from ``derivative``
        differences of the rates.
    reference : BicycleParameters or CanonicalMatrices, optional
        Values of the fixed entries (Whipple model of the bicycle); default the
        ``meta['parameters']`` of the first run.
    free_roll, free_steer : sequence of str, optional
        Entry names to estimate in the roll and steer rows; defaults are Moore &
        Hubbard's sets (:data:`MOORE_ROLL`, :data:`MOORE_STEER`), with HdF left out
        when F is zero in every run.
    fixed : dict of str to float, optional
        Overrides single fixed entries (units of their matrix).
    H : (float, float), optional
        (HpF, HdF) [m], the fixed lateral-force entries (default 0).
    symmetric : bool, optional
        Two-stage, Mdp := Mpd and K0dp := K0pd from the roll row (the paper's procedure).
    method : {"ls", "iv"}, optional
        Least squares or instrumental variables (two-stage least squares).
    instruments : {"lagged", "dither", "external", "simulated"}, optional
        Instrument set for ``method="iv"`` (module docstring).
    lags : int, optional
        Number of lags [samples], >= 1 (not used by "simulated"); the first ``lags``
        samples of each run are dropped.
    source : {"signals", "truth"}, optional
        Measured signals or the noise-free simulated ones.
    derivative : str, optional
        Difference scheme of :func:`ident.signals.differentiate` for accelerations
        missing from the run.
    max_condition : float, optional
        An unidentifiable setup (condition number of the column-scaled regressor matrix
        above this) raises ValueError naming the collinear entries.
    instrument_runs : sequence of Run, optional
        For ``instruments="simulated"``, one noise-free run per run (same samples,
        prepared the same way) whose regressors are the instruments.
    covariance : {"white", "run"}, optional
        "white" (the paper's sigma^2 (Gamma' Gamma)^-1) or "run" (cluster-robust over
        runs, for coloured equation errors; module docstring).
    informativity : {"refuse", "report", "skip"}, optional
        Before the regression, whether the runs' steer torque can determine the free
        entries, with excited runs at two or more speeds when they span two
        (:func:`bikeid.ident.informativity.guard`): refuse when they cannot (default), or
        estimate and say so in ``notes``, or skip the check (``notes`` says so).

    Returns
    -------
    DirectResult
        The matrices with the fixed and estimated entries, standard errors, covariances,
        condition numbers and torque fits.

    Raises
    ------
    ValueError
        If no runs are given; runs break the sampling contract
        (``ident.signals.check_sampling``); an option is not one of its choices; an entry
        name is unknown or in the wrong row; ``instrument_runs``, a logged dither or
        reference are missing for the chosen instruments; no reference values are
        available; a row's right-hand side is zero; or a row is unidentifiable (K0 and
        K2 of the same entry free at one speed, or condition number above
        ``max_condition``), naming the collinear entries.
    UntrustworthyResult
        If the runs cannot determine the model and ``informativity`` is ``"refuse"``
        (a subclass of ValueError).
    """
    runs = [runs] if isinstance(runs, Run) else list(runs)
    if not runs:
        raise ValueError("no runs given")
    check_sampling(runs, "direct.identify")
    if method not in ("ls", "iv"):
        raise ValueError(f"method {method!r}: choose 'ls' or 'iv'")
    if instruments not in ("lagged", "dither", "external", "simulated"):
        raise ValueError(
            f"instruments {instruments!r}: choose 'lagged', 'dither', 'external' or 'simulated'"
        )
    simulated = method == "iv" and instruments == "simulated"
    if simulated:
        if instrument_runs is None or len(instrument_runs) != len(runs):
            raise ValueError(
                "instruments='simulated' needs instrument_runs: one simulated run per run "
                "(ident.tailored_iv.identify_tailored builds them)"
            )
        for r, z in zip(runs, instrument_runs, strict=True):
            if z.n != r.n:
                raise ValueError(
                    f"instrument run has {z.n} samples, its data run {r.n}: prepare both alike"
                )
    if method == "iv" and not simulated and lags < 1:
        raise ValueError(f"lags={lags}: instrumental variables need lags >= 1")
    if source not in ("signals", "truth"):
        raise ValueError(f"source {source!r}: choose 'signals' or 'truth'")
    if covariance not in ("white", "run"):
        raise ValueError(f"covariance {covariance!r}: choose 'white' or 'run'")
    if covariance == "run" and len(runs) < 2:
        raise ValueError("covariance='run' needs at least 2 runs (runs are the clusters)")
    if reference is None:
        if "parameters" not in runs[0].meta:
            raise ValueError(
                "no reference values for the fixed entries: pass reference=BicycleParameters"
            )
        reference = from_mapping(runs[0].meta["parameters"], name="run meta")
    vals, g = _reference_values(reference, H)
    for k, val in (fixed or {}).items():
        parse_entry(k)
        vals[k] = float(val)

    data = [_data(r, source, derivative) for r in runs]
    notes = []
    no_force = all(not np.any(d["F"]) for d in data)
    if free_roll is None:
        free_roll = MOORE_ROLL
    if free_steer is None:
        free_steer = MOORE_STEER
        if no_force:
            free_steer = tuple(n for n in free_steer if n != "HdF")
            notes.append("HdF not estimated: F is zero in every run")
    free_roll, free_steer = tuple(free_roll), tuple(free_steer)
    for row, names in (("roll", free_roll), ("steer", free_steer)):
        want = 0 if row == "roll" else 1
        for n in names:
            if parse_entry(n)[1] != want:
                raise ValueError(f"entry {n!r} is not in the {row} row")
        if len(set(names)) != len(names) or not names:
            raise ValueError(f"{row} free set {names} must be non-empty without repeats")
    if symmetric:
        clash = [n for n in ("Mdp", "K0dp") if n in free_steer]
        if clash:
            raise ValueError(
                f"{clash} are set by symmetry from the roll row: drop them from free_steer or "
                "pass symmetric=False"
            )
    if method == "iv" and instruments == "dither" and any(r.dither is None for r in runs):
        raise ValueError("instruments='dither' needs runs with a logged dither")
    if (
        method == "iv"
        and instruments == "external"
        and any(r.dither is None or r.reference is None for r in runs)
    ):
        raise ValueError("instruments='external' needs runs with a logged dither and reference")

    est = "least-squares" if method == "ls" else "instrumental-variables"
    _, told = guard(runs, len(free_roll) + len(free_steer), what=f"the direct {est} model",
                    informativity=informativity, min_speeds=2)  # fmt: skip
    if told:
        notes.append(told)
    cols = [regressors(d, g) for d in data]
    speeds = np.concatenate([d["v"] for d in data])
    one_speed = np.ptp(speeds) <= 1e-9 * max(1.0, float(np.abs(speeds).max()))
    # One nominal speed measured with noise is still one speed: the v^2 column then differs
    # from the g column only by sensor noise, which a finite condition number hides.
    means = np.array([float(np.mean(d["v"])) for d in data])
    wobble = max(float(np.std(d["v"])) for d in data)
    nominal_one_speed = np.ptp(means) < 0.1 and wobble < 0.02 * max(float(np.mean(means)), 1e-9)
    if nominal_one_speed:
        for row, names in (("roll", free_roll), ("steer", free_steer)):
            r = "pd"[row == "steer"]
            for c in "pd":
                pair = [f"K0{r}{c}", f"K2{r}{c}"]
                if all(n in names for n in pair):
                    G = np.column_stack([np.concatenate([k[n] for k in cols]) for n in pair])
                    cond_now, _ = _condition(G)
                    raise UntrustworthyResult(
                        f"{row} row is unidentifiable: {pair[0]} and {pair[1]} are both free "
                        f"but the runs cover one speed ({means.min():.3f}-{means.max():.3f} "
                        f"m/s, within-run std {wobble:.3g} m/s); a single constant speed cannot "
                        "separate K0 from K2: g q and v^2 q differ only by speed noise "
                        f"(condition number {cond_now:.3g} of the two columns; "
                        "infinite at the nominal speed). Fix one of them at a known value or "
                        "add runs at other speeds."
                    )
    cut = lags if method == "iv" and not simulated else 0
    inst_cols = (
        [regressors(_data(z, "signals", derivative), g) for z in instrument_runs]
        if simulated
        else None
    )

    def stack(f) -> np.ndarray:
        return np.concatenate([f(i)[cut:] for i in range(len(runs))])

    def instrument_matrix(names) -> np.ndarray | None:
        if method == "ls":
            return None
        if simulated:
            return np.column_stack([stack(lambda i, n=n: inst_cols[i][n]) for n in names])
        if instruments == "lagged":
            return np.column_stack(
                [np.concatenate([cols[i][n][:-cut] for i in range(len(runs))]) for n in names]
            )
        zs = []
        if instruments == "external":
            step = max(1, lags // 20)
            for sig in ("dither", "reference"):
                for j in range(0, lags + 1, step):
                    for pw in (0, 1, 2):
                        zs.append(stack(lambda i, j=j, pw=pw, sig=sig: np.roll(
                            getattr(runs[i], sig) - getattr(runs[i], sig).mean(), j
                        ) * data[i]["v"] ** pw))  # fmt: skip
            return np.column_stack(zs)
        for j in range(lags + 1):
            for pw in (0, 1, 2):
                zs.append(
                    stack(lambda i, j=j, pw=pw: np.roll(runs[i].dither, j) * data[i]["v"] ** pw)
                )
        return np.column_stack(zs)

    hints_common = []
    for c in "pd":
        hints_common.append(
            (
                (f"K0{{r}}{c}", f"K2{{r}}{c}"),
                " A single constant speed cannot separate K0 from K2 (g q and v^2 q are "
                "collinear): add runs at other speeds or per-sample speed variation."
                if one_speed
                else "",
            )
        )

    results: dict[str, tuple] = {}
    cond: dict[str, float] = {}
    for row, r_idx, names in (("roll", 0, free_roll), ("steer", 1, free_steer)):
        if row == "steer" and symmetric:
            for a, b in (("Mdp", "Mpd"), ("K0dp", "K0pd")):
                vals[a] = vals[b]
        rhs_name = "T_phi" if r_idx == 0 else "T_delta"
        row_entries = [n for n in ALL_ENTRIES if parse_entry(n)[1] == r_idx]
        fixed_names = [n for n in row_entries if n not in names]

        def rhs(i, fixed_names=fixed_names, rhs_name=rhs_name) -> np.ndarray:
            y = data[i][rhs_name].copy()
            for n in fixed_names:
                y -= vals[n] * cols[i][n]
            return y

        Y = stack(rhs)
        G = np.column_stack([stack(lambda i, n=n: cols[i][n]) for n in names])
        hints = [(tuple(k.format(r="pd"[r_idx]) for k in key), h) for key, h in hints_common]
        if row == "steer" and no_force and not any(np.any(d["T_phi"]) for d in data):
            hints.append(
                (("Mdp", "Mdd", "C1dp", "C1dd", "K0dp", "K0dd", "K2dd"),
                 " With T_phi = F = 0 the roll equation is an exact linear relation among these"
                 " steer regressors: fix Mdp and K0dp (symmetric=True) or another entry.")
            )  # fmt: skip
        if not np.any(Y):
            raise ValueError(
                f"{row} row has a zero right-hand side (T = F = 0 and no fixed nonzero entry), "
                f"so its scale is undetermined: fix at least one {row} entry, e.g. "
                f"{'Mpp' if r_idx == 0 else 'Mdd'}, at a known value"
            )
        ends = np.cumsum([d["v"].size - cut for d in data])
        clusters = list(zip(np.r_[0, ends[:-1]], ends, strict=True))
        theta, cov, cond[row] = _solve_row(
            row, names, G, Y, instrument_matrix(names), max_condition, hints,
            clusters if covariance == "run" else None,
        )  # fmt: skip
        for n, th in zip(names, theta, strict=True):
            vals[n] = float(th)
        results[row] = (names, theta, cov)

    Mats = {m: np.array([[vals[f"{m}{r}{c}"] for c in "pd"] for r in "pd"]) for m in _MATS}
    Hvec = np.array([vals["HpF"], vals["HdF"]])
    vm, vv = {}, {}
    for row, r_idx in (("roll", 0), ("steer", 1)):
        rhs_name = "T_phi" if r_idx == 0 else "T_delta"
        entries = [n for n in ALL_ENTRIES if parse_entry(n)[1] == r_idx and not n.startswith("H")]
        ym = np.concatenate([d[rhs_name] + Hvec[r_idx] * d["F"] for d in data])
        yp = np.concatenate([sum(vals[n] * c[n] for n in entries) for c in cols])
        vm[row], vv[row] = vaf_moore(ym, yp), vaf_variance(ym, yp)
    free = {n: vals[n] for row in results for n in results[row][0]}
    stderr = {}
    covs = {}
    for row, (names, _, cov) in results.items():
        covs[row] = (names, cov)
        for n, s in zip(names, np.sqrt(np.diag(cov)), strict=True):
            stderr[n] = float(s)
    return DirectResult(
        M=Mats["M"], C1=Mats["C1"], K0=Mats["K0"], K2=Mats["K2"], H=Hvec, g=g,
        free=free, stderr=stderr, covariance=covs, condition=cond, vaf_moore=vm,
        vaf_variance=vv, n_samples=int(Y.size), method=f"{method}" + (
            f" ({instruments}" + ("" if simulated else f", lags={lags}") + ")"
            if method == "iv" else ""),
        notes=tuple(notes),
    )  # fmt: skip
