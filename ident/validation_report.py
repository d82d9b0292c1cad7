"""A model's validation report on data: compare, k-step prediction, resid, and Bode vs data.

:func:`validate_model` gathers, for one model and one or more runs, what a reader needs to
judge the model (MATLAB System Identification Toolbox habits, all built on
:mod:`bikeid.ident.validate`):

- measured outputs against the simulated (:func:`~bikeid.ident.validate.compare`, horizon
  None) and the k-step-ahead predicted outputs (``horizon = k``), with MATLAB ``compare``'s
  NRMSE fit 100 (1 - ||y - yhat|| / ||y - mean y||) [%] per output;
- one-step residuals (:func:`~bikeid.ident.validate.resid`): autocorrelation and
  residual-input cross-correlation with the 99 % band per speed, judged by the one residual
  test of the project, :func:`bikeid.ident.structure.check_structure` (whiteness when the
  model has a noise model, independence from the past input; the test ``bikeid identify``
  runs before it prints intervals, so both say the same of the same data);
- a nonparametric frequency response from the steer torque to each output
  (:func:`frequency_response_estimate`, Welch spectra), kept only at frequencies whose
  coherence shows excitation, to lay over the model's Bode plot, with the model's 95 %
  Bode band (:func:`bikeid.ident.uncertainty.bode_bands`, for models with a parameter
  covariance) and which estimated points lie inside it.

The runs are taken one speed at a time and reduced to fits, correlations and spectra
before the next speed, keeping the time series of the first :data:`SERIES_RUNS` runs only
(the compare figures).  The result, :class:`ValidationReport`, turns into plain JSON types with
:meth:`ValidationReport.to_json`; the figures are drawn by
:mod:`bikeid.experiments.validation_plots`.  :func:`validate_decays` applies the same fit and
residual tests to the steer-by-wire experiment model on measured free decays (``bikeid
measured evaluate``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from bikeid.dataset.run import SPEED_TOLERANCE, Run
from bikeid.ident.direct import DirectResult
from bikeid.ident.greybox import GreyboxModel
from bikeid.ident.structure import StructureCheck, _speeds_text
from bikeid.ident.uncertainty import bode_bands, z_value
from bikeid.ident.validate import (
    compare,
    cross_correlation,
    goodness_of_fit,
    resid,
    sampled_model,
    whiteness,
)
from bikeid.sim.errors import InputError, UntrustworthyResult

__all__ = [
    "INTERVAL_CALIBRATION",
    "Correlations",
    "FrequencyResponseEstimate",
    "RunSeries",
    "SpeedRow",
    "ValidationReport",
    "bode_band_halfwidths",
    "frequency_response_estimate",
    "model_frequency_response",
    "residual_tests",
    "validate_decays",
    "validate_model",
]

#: Default coherence below which a frequency counts as not excited (dimensionless, 0-1).
COHERENCE_MIN = 0.5
#: Default prediction horizon k of the k-step-ahead comparison [samples].
K_STEP = 10
#: Speeds closer than this share one frequency-response estimate [m/s].
SPEED_GROUP = 0.01
#: Confidence level of the model's Bode band.
BAND_LEVEL = 0.95
#: What every printed interval says about itself (docs/uncertainty.md).
INTERVAL_CALIBRATION = (
    "95 % intervals of eigenvalues and critical speeds are profile intervals (the ends over the "
    "parameters' confidence ellipsoid from the fit's covariance), Bode bands first-order; "
    "their coverage is calibrated on the linear plant only (docs/uncertainty.md), not on the "
    "nonlinear plant or measured data, where they can be too narrow"
)


def _runs(runs: Run | Sequence[Run]) -> list[Run]:
    runs = [runs] if isinstance(runs, Run) else list(runs)
    if not runs:
        raise ValueError("no runs to validate on: give at least one run")
    return runs


def _label(run: Run, i: int) -> str:
    return str(run.meta.get("name") or run.meta.get("file") or f"run {i + 1}")


def model_frequency_response(
    model, f: np.ndarray, dt: float, v: float | None = None, input: str = "T_delta"
) -> dict[str, np.ndarray]:
    """The model's frequency response as seen by sampled data (zero-order-hold input).

    H(e^{j 2 pi f dt}) = C (z I - Ad)^-1 Bd of the model sampled exactly at ``dt``
    (:func:`~bikeid.ident.validate.sampled_model`): the response a nonparametric estimate
    from data logged at ``dt`` with a held input tends to (up to the Nyquist frequency
    1 / (2 dt) it differs from the continuous H(j 2 pi f) by the hold's delay of dt / 2 and
    the hold's sinc magnitude).

    Parameters
    ----------
    model : CanonicalModel, SpeedCanonicalModel, GreyboxModel, DirectResult or StateSpace
        The model.
    f : (F,) array_like
        Frequencies [Hz], below the Nyquist frequency.
    dt : float
        Sample period [s].
    v : float, optional
        Speed [m/s] (models defined over speed).
    input : str, optional
        The input column.

    Returns
    -------
    dict of str to (F,) complex ndarray
        Per output, the response in output units per input unit (rad/(N m), rad/(N m s)).

    Raises
    ------
    ValueError
        If the model has no such input (or :func:`sampled_model` refuses it).
    """
    Ad, Bd, C, _, outputs, inputs = sampled_model(model, dt, v)
    if input not in inputs:
        raise ValueError(f"the model has no input {input!r}; its inputs are {list(inputs)}")
    b = Bd[:, inputs.index(input)]
    n = Ad.shape[0]
    z = np.exp(2j * np.pi * np.asarray(f, float) * dt)
    H = np.array([C @ np.linalg.solve(zk * np.eye(n) - Ad, b) for zk in z]).reshape(len(z), -1)
    return {o: H[:, j] for j, o in enumerate(outputs)}


@dataclass(frozen=True)
class FrequencyResponseEstimate:
    """A nonparametric frequency response from the steer torque to one output.

    Attributes
    ----------
    output : str
        Output signal (e.g. ``"phi"``).
    input : str
        Input signal of the response (``"T_delta"``).
    reference : str
        The excitation the spectra are taken against: ``"dither"`` (closed-loop safe ratio
        S_dy / S_du), ``"T_delta"`` (H1 = S_uy / S_uu, open loop) or ``"none"``.
    speed : float
        Speed of the runs [m/s].
    f : (F,) ndarray
        Frequencies [Hz] (0 excluded).
    H : (F,) complex ndarray
        Estimated response [output unit / N m].
    coherence : (F,) ndarray
        Coherence of the excitation with the signals used (the smaller of the two for the
        dither ratio), 0-1.
    rel_error : (F,) ndarray
        First-order random error of ``H`` relative to |H| (standard deviation of each of
        the real and imaginary parts of (H_est - H) / H): sqrt(1 - g^2) / (|g| sqrt(2 n_d))
        per spectral ratio (Bendat & Piersol, *Random Data*, eq. 9.90), the two of the
        dither ratio added in quadrature; n_d counts non-overlapping segments (conservative
        for Welch's 50 % overlap).
    valid : (F,) bool ndarray
        Frequencies with coherence >= the threshold (excitation allows an estimate).
    model : (F,) complex ndarray
        The model's sampled response at ``f`` (:func:`model_frequency_response`).
    n_averages : int
        n_d, the number of non-overlapping segments averaged.
    coherence_min : float
        The threshold used.
    note : str
        Empty, or why there is no estimate ("not enough excitation: ...") or how to read it.
    model_f : (G,) ndarray
        A log-spaced grid [Hz] from f[0] / 4 to 0.98 of the Nyquist frequency, for drawing.
    model_curve : (G,) complex ndarray
        The model's sampled response on ``model_f``.
    band_db, band_deg : (F,) ndarray
        Half-widths of the model's 95 % Bode band at ``f`` [dB, deg]
        (:func:`bikeid.ident.uncertainty.bode_bands`: z times the standard errors of
        20 log10 |G| and of the phase), laid about ``model``; empty when the model has no
        parameter covariance (direct, StateSpace).
    curve_band_db, curve_band_deg : (G,) ndarray
        The same half-widths on ``model_f`` (for drawing).
    """

    output: str
    input: str
    reference: str
    speed: float
    f: np.ndarray
    H: np.ndarray
    coherence: np.ndarray
    rel_error: np.ndarray
    valid: np.ndarray
    model: np.ndarray
    n_averages: int
    coherence_min: float
    note: str = ""
    model_f: np.ndarray = field(default_factory=lambda: np.zeros(0))
    model_curve: np.ndarray = field(default_factory=lambda: np.zeros(0, complex))
    band_db: np.ndarray = field(default_factory=lambda: np.zeros(0))
    band_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    curve_band_db: np.ndarray = field(default_factory=lambda: np.zeros(0))
    curve_band_deg: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def excited(self) -> bool:
        """bool: True when at least one frequency has enough coherence for an estimate."""
        return bool(np.any(self.valid))

    @property
    def in_band(self) -> np.ndarray | None:
        """(F,) bool ndarray or None: valid estimates whose magnitude (dB) and phase both lie
        inside the model's 95 % Bode band (None without a band)."""
        if self.band_db.size == 0:
            return None
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = self.H / self.model
            d_db = np.abs(20.0 * np.log10(np.abs(ratio)))
            d_deg = np.abs(np.degrees(np.angle(ratio)))
        return self.valid & (d_db <= self.band_db) & (d_deg <= self.band_deg)

    @property
    def consistent(self) -> np.ndarray | None:
        """(F,) bool ndarray or None: valid estimates within the band widened by their own
        95 % random error (half-widths added in quadrature: sqrt(band^2 + (z e)^2), e the
        relative error :attr:`rel_error` as sd of ln|H| and of the phase [rad]); None
        without a band.  The estimate is usually noisier than the model, so this, not
        :attr:`in_band`, says whether model and data disagree."""
        if self.band_db.size == 0:
            return None
        ze = z_value(BAND_LEVEL) * self.rel_error
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = self.H / self.model
            d_db = np.abs(20.0 * np.log10(np.abs(ratio)))
            d_deg = np.abs(np.degrees(np.angle(ratio)))
        w_db = np.hypot(self.band_db, ze * 20.0 / np.log(10.0))
        w_deg = np.hypot(self.band_deg, np.degrees(ze))
        return self.valid & (d_db <= w_db) & (d_deg <= w_deg)

    def to_json(self) -> dict:
        """The estimate at its valid frequencies, as plain JSON types.

        Returns
        -------
        dict
            ``output``, ``input``, ``reference``, ``speed`` [m/s], ``coherence_min``,
            ``n_averages``, ``note``, the excited band ``f_min``/``f_max`` [Hz] (None when
            there is none) and, at the valid frequencies only, ``f`` [Hz], ``H_re``,
            ``H_im``, ``model_re``, ``model_im`` [output unit / N m], ``coherence`` and
            ``rel_error``; ``band`` (None without a parameter covariance): ``level``,
            half-widths ``db`` and ``deg`` and ``inside`` per valid frequency,
            ``n_inside`` and ``n_consistent`` (:attr:`consistent`) of ``n_points``.
        """
        v = self.valid
        fv = self.f[v]
        inside = self.in_band
        band = None if inside is None else {
            "level": BAND_LEVEL, "db": self.band_db[v].tolist(), "deg": self.band_deg[v].tolist(),
            "inside": inside[v].tolist(), "n_inside": int(inside.sum()), "n_points": int(v.sum()),
            "n_consistent": int(self.consistent.sum()),
        }  # fmt: skip
        return {
            "output": self.output, "input": self.input, "reference": self.reference,
            "speed": float(self.speed), "coherence_min": float(self.coherence_min),
            "n_averages": int(self.n_averages), "note": self.note,
            "f_min": float(fv.min()) if fv.size else None,
            "f_max": float(fv.max()) if fv.size else None,
            "f": fv.tolist(), "H_re": self.H[v].real.tolist(), "H_im": self.H[v].imag.tolist(),
            "model_re": self.model[v].real.tolist(), "model_im": self.model[v].imag.tolist(),
            "coherence": self.coherence[v].tolist(), "rel_error": self.rel_error[v].tolist(),
            "band": band,
        }  # fmt: skip


def bode_band_halfwidths(model, f: np.ndarray, v: float) -> dict | None:
    """Half-widths [dB, deg] of a model's 95 % Bode band per output, or None.

    Parameters
    ----------
    model : CanonicalModel, SpeedCanonicalModel, GreyboxModel, DirectResult or StateSpace
        The model; a band exists for those with a parameter covariance (a model over speed
        is taken at ``v`` with :meth:`at`).
    f : (F,) ndarray
        Frequencies [Hz], positive.
    v : float
        Speed [m/s].

    Returns
    -------
    dict of str to ((F,) ndarray, (F,) ndarray) or None
        Per output, z times the standard errors of 20 log10 |G| [dB] and of the phase [deg]
        (:func:`bikeid.ident.uncertainty.bode_bands` at ``BAND_LEVEL``); None for a model
        without covariance.
    """
    m = model.at(v) if hasattr(model, "at") else model
    if not (hasattr(m, "predictor") and hasattr(m, "covariance")):
        return None
    z = z_value(BAND_LEVEL)
    try:
        bands = bode_bands(m, 2 * np.pi * np.asarray(f, float), level=BAND_LEVEL)
    except InputError:  # no usable (finite) covariance: no band, as for a direct model
        return None
    except UntrustworthyResult:  # refused as the intervals are (ident.trust): no band
        return None
    return {b.output: (z * b.std_magnitude_db, z * b.std_phase_deg) for b in bands}


def _nperseg(n_min: int) -> int:
    """Segment length: a power of two giving >= 8 segments of the shortest run, 32..1024."""
    return int(min(1024, max(32, 2 ** int(np.floor(np.log2(max(n_min, 2) / 8))))))


def _excitation(runs: list[Run], input: str) -> tuple[str, str]:
    """(reference, note): which signal excites the loop, or why none does."""
    dithers = [r.dither for r in runs]
    if all(d is not None and np.any(d) for d in dithers):
        return "dither", ""
    if any(d is not None for d in dithers):
        return "none", (
            "not enough excitation: a run has a zero (or no) dither, so T_delta is only the "
            "controller's feedback and its spectra would estimate -1/controller, not the "
            "bicycle; record runs with a dither (e.g. bikeid sweep --dither)"
        )
    if any("controller" in r.meta for r in runs):
        return "none", (
            "not enough excitation: closed-loop runs without a logged dither; T_delta is the "
            "controller's feedback, so its spectra would estimate -1/controller"
        )
    return input, (
        f"{input} taken as the excitation (no dither logged): right in open loop; in closed "
        "loop, where noise drives the feedback, the estimate tends to -1/controller"
    )


def frequency_response_estimate(
    runs: Run | Sequence[Run],
    model,
    coherence_min: float = COHERENCE_MIN,
    nperseg: int | None = None,
    input: str = "T_delta",
) -> list[FrequencyResponseEstimate]:
    """Welch estimate of the response from ``input`` to each model output, with coherence.

    With a logged dither d in every run (closed loop), the estimate is the ratio
    S_dy / S_du of cross-spectra with the dither, which is the plant's response however the
    loop is closed (the joint input-output method; Ljung sec. 13.5), and the coherence is
    the smaller of those of d with y and with u.  Without a dither field (imported logs
    without a controller in their metadata), it is H1 = S_uy / S_uu with the coherence of u
    and y.  Closed-loop runs without excitation (a zero dither, or a controller and no dither)
    get no estimate and a note saying "not enough excitation".  Runs are grouped by speed
    (one estimate per group); spectra are averaged over the runs' segments (Hann window,
    50 % overlap, mean removed).

    Parameters
    ----------
    runs : Run or sequence of Run
        The data (same sample period).
    model : CanonicalModel, SpeedCanonicalModel, GreyboxModel, DirectResult or StateSpace
        The model whose outputs name the signals, and whose response is laid beside it.
    coherence_min : float, optional
        Frequencies with coherence below this are not estimated (``valid`` False).
    nperseg : int, optional
        Welch segment length [samples]; default a power of two giving at least 8 segments
        of the shortest run (32..1024).
    input : str, optional
        The input signal of the response.

    Returns
    -------
    list of FrequencyResponseEstimate
        One per (speed group, output), in speed then output order.

    Raises
    ------
    ValueError
        If the runs' sample periods differ, ``coherence_min`` is outside (0, 1), or a run is
        shorter than the segment length.
    """
    runs = _runs(runs)
    if not 0 < coherence_min < 1:
        raise ValueError(f"coherence_min={coherence_min}: need a value in (0, 1)")
    dt = runs[0].dt
    if any(abs(r.dt - dt) > 1e-9 * dt for r in runs):
        raise ValueError("the runs have different sample periods; validate them separately")
    groups: dict[float, list[Run]] = {}
    for r in runs:
        key = next((s for s in groups if abs(s - r.speed) <= SPEED_GROUP), r.speed)
        groups.setdefault(key, []).append(r)
    out = []
    for v, rs in groups.items():
        nps = nperseg or _nperseg(min(r.n for r in rs))
        short = [r.n for r in rs if r.n < nps]
        if short:
            raise ValueError(f"a run has {short[0]} samples, fewer than the segment {nps}")
        reference, note = _excitation(rs, input)
        f = np.fft.rfftfreq(nps, dt)[1:]
        outputs = sampled_model(model, dt, v)[4]
        Gm = model_frequency_response(model, f, dt, v, input)
        fd = np.geomspace(f[0] / 4, 0.98 / (2 * dt), 300)
        Gd = model_frequency_response(model, fd, dt, v, input)
        band = bode_band_halfwidths(model, f, v) if input == "T_delta" else None
        band_d = bode_band_halfwidths(model, fd, v) if band else None
        n_d = sum(r.n // nps for r in rs)
        for o in outputs:
            bk = {} if band is None else {"band_db": band[o][0], "band_deg": band[o][1],
                                          "curve_band_db": band_d[o][0],
                                          "curve_band_deg": band_d[o][1]}  # fmt: skip
            if reference == "none":
                nan = np.full(f.size, np.nan)
                out.append(FrequencyResponseEstimate(
                    o, input, reference, v, f, nan + 0j, nan, nan, np.zeros(f.size, bool),
                    Gm[o], n_d, coherence_min, note, fd, Gd[o], **bk))  # fmt: skip
                continue
            spec = dict.fromkeys(("xx", "xy", "xu", "yy", "uu"), 0.0)
            for r in rs:
                x = r.dither if reference == "dither" else r[input]
                sig = {"x": x, "y": r[o], "u": r[input]}
                kw = {"fs": 1 / dt, "nperseg": nps, "detrend": "constant"}
                w = r.n // nps  # weight each run by its share of segments
                for k in spec:
                    a, b = sig[k[0]], sig[k[1]]
                    spec[k] = spec[k] + w * signal.csd(a, b, **kw)[1][1:]
            g_xy = np.abs(spec["xy"]) ** 2 / (spec["xx"].real * spec["yy"].real)
            if reference == "dither":
                g_xu = np.abs(spec["xu"]) ** 2 / (spec["xx"].real * spec["uu"].real)
                H = spec["xy"] / spec["xu"]
                coh = np.minimum(g_xy, g_xu)
                err = np.sqrt((1 - g_xy) / (2 * n_d * g_xy) + (1 - g_xu) / (2 * n_d * g_xu))
            else:
                H = spec["xy"] / spec["xx"].real
                coh = g_xy
                err = np.sqrt((1 - g_xy) / (2 * n_d * g_xy))
            valid = coh >= coherence_min
            text = note
            if not valid.any():
                text = (
                    f"not enough excitation: coherence below {coherence_min} at every "
                    f"frequency (largest {np.nanmax(coh):.2f}); excite the loop more or "
                    "average more data"
                )
            out.append(FrequencyResponseEstimate(o, input, reference, v, f, H, coh, err,
                                                 valid, Gm[o], n_d, coherence_min, text,
                                                 fd, Gd[o], **bk))  # fmt: skip
    return out


def residual_tests(
    residuals: Sequence[np.ndarray],
    inputs: Sequence[np.ndarray] | None,
    names: Sequence[str],
    max_lag: int = 25,
    confidence: float = 0.99,
) -> dict[str, dict]:
    """Whiteness and input-independence tests of residuals given as arrays.

    The tests of :func:`bikeid.ident.validate.resid`, for residuals computed elsewhere (e.g.
    the simulation errors of the experiment model on measured decays): the residuals of all
    segments are stacked, then :func:`~bikeid.ident.validate.whiteness` and
    :func:`~bikeid.ident.validate.cross_correlation` are applied.

    Parameters
    ----------
    residuals : sequence of (N_i, p) ndarray
        Residuals per segment, one column per name (output units).
    inputs : sequence of (N_i,) ndarray or None
        The input per segment (N m), or None (no independence test).
    names : sequence of str
        The p output names.
    max_lag : int, optional
        Largest lag [samples].
    confidence : float, optional
        Band level; the tests' level is 1 - confidence.

    Returns
    -------
    dict of str to dict
        Per name: ``white`` (bool), ``whiteness_p``, ``fraction_outside`` (autocorrelation
        lags 1..max_lag outside the band), and with inputs ``independent`` (bool) and
        ``independence_p``; ``band`` and ``n`` (samples).
    """
    E = np.vstack([np.asarray(r, float).reshape(len(r), -1) for r in residuals])
    u = None if inputs is None else np.concatenate([np.asarray(x, float) for x in inputs])
    out = {}
    for j, name in enumerate(names):
        w = whiteness(E[:, j], max_lag, confidence)
        row = {"n": int(E.shape[0]), "band": w["band"], "fraction_outside": w["fraction_outside"],
               "white": bool(w["test"]["passed"]), "whiteness_p": w["test"]["p_value"]}  # fmt: skip
        if u is not None and np.any(u - u.mean()):
            c = cross_correlation(E[:, j], u, max_lag, confidence)
            row.update(independent=bool(c["test"]["passed"]), independence_p=c["test"]["p_value"])
        out[name] = row
    return out


#: Runs whose time series a report keeps for the compare figures (the first ones).
SERIES_RUNS = 6


@dataclass(frozen=True)
class RunSeries:
    """Time series of one run kept for the compare figure.

    Attributes
    ----------
    label : str
        Run label.
    speed : float
        Speed [m/s].
    t : (N,) ndarray
        Time [s].
    measured, predicted : (N, p) ndarray
        Measured and k-step-predicted outputs (columns in the report's ``outputs`` order;
        rad, rad/s).
    simulated : (N, p) ndarray or None
        Simulated outputs (None where the simulation was refused).
    fit : dict
        ``{"simulation": {output: %} or None, "k_step": {output: %}}``.
    """

    label: str
    speed: float
    t: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    simulated: np.ndarray | None
    fit: dict


@dataclass(frozen=True)
class Correlations:
    """Residual correlations of the runs at one speed, for the resid figure.

    Attributes
    ----------
    speed : float
        Speed of the group [m/s].
    n : int
        Samples stacked.
    band : float
        Half-width of the 99 % band of a white residual, z / sqrt(n).
    lags : (2 M + 1,) int ndarray
        Lags -M..M [samples] of ``crosscorr``.
    autocorr : dict of str to (M + 1,) ndarray
        Normalized autocorrelation of each output's one-step residual at lags 0..M.
    crosscorr : dict of str to (2 M + 1,) ndarray
        Normalized cross-correlation with T_delta at ``lags`` (positive lag: residual at k
        against T_delta at k - lag), the input of :mod:`bikeid.ident.structure`'s
        independence test.
    """

    speed: float
    n: int
    band: float
    lags: np.ndarray
    autocorr: dict[str, np.ndarray]
    crosscorr: dict[str, np.ndarray]


@dataclass(frozen=True)
class SpeedRow:
    """The one-line verdict of the runs at one speed.

    Attributes
    ----------
    speed : float
        Speed [m/s] (runs within :data:`SPEED_GROUP` of it).
    runs : int
        Number of runs.
    fit_simulation : dict of str to float or None
        Simulation fit per output over the runs [%]; None when refused at this speed.
    fit_k_step : dict of str to float
        k-step prediction fit per output [%].
    whiteness : dict of str to dict or None
        Per output the whiteness test of :func:`bikeid.ident.structure.check_structure`
        (``white``, ``p_value``, ``per_test_level``); None when the check makes none (a
        model without a noise model, K = 0).
    independence : dict of str to dict
        Per output the structure check's test of independence from the past input
        (``independent``, ``p_value``).
    frf : dict
        ``n_points`` (excited frequencies over the outputs), ``n_inside`` and
        ``n_consistent`` (None without a Bode band), and ``fraction`` inside (None without
        points or band).
    """

    speed: float
    runs: int
    fit_simulation: dict[str, float] | None
    fit_k_step: dict[str, float]
    whiteness: dict[str, dict] | None
    independence: dict[str, dict]
    frf: dict

    def to_json(self) -> dict:
        """The row as plain JSON types.

        Returns
        -------
        dict
            The fields by name (:func:`bikeid.sim.textformats.to_jsonable`).
        """
        from bikeid.sim.textformats import to_jsonable

        return to_jsonable(dataclasses.asdict(self))


@dataclass(frozen=True)
class ValidationReport:
    """How a model meets data: fits, residual tests and frequency responses, per speed.

    Computed one speed at a time (:func:`validate_model`): it keeps the time series of the
    first few runs only (:attr:`series`), so its size does not grow with the runs' length.

    Attributes
    ----------
    outputs : tuple of str
        Output names (rad, rad/s).
    runs : tuple of str
        Run labels (``meta["name"]`` or ``meta["file"]``, else "run i").
    speeds : tuple of float
        Speed of each run [m/s].
    k_step : int
        The prediction horizon k [samples] (MATLAB ``compare(data, model, k)``).
    headline : {"simulation", "k_step"}
        The fit the summary leads with: the simulation's when the model could be simulated
        at every speed, else the k-step prediction's (:attr:`simulation_note` says why).
    simulation_note : str
        Where and why the simulation was refused, or "".
    fit : dict of str to float or None
        Simulation fit per output over all runs [%] (MATLAB ``compare``'s NRMSE fit x 100);
        None when the simulation was refused at any speed.
    fit_k_step : dict of str to float
        k-step prediction fit per output over all runs [%].
    fit_per_run : tuple of dict
        Per run: ``{"simulation": {output: %} or None, "k_step": {output: %}}``.
    per_speed : tuple of SpeedRow
        Per speed: fits, the structure check's residual verdicts, Bode-band counts.
    structure : StructureCheck
        :func:`bikeid.ident.structure.check_structure` on these runs: the residual tests
        (whiteness, independence from the past input, and for a model over speed the
        comparison with its per-speed fits), as ``bikeid identify`` runs them.
    correlations : tuple of Correlations
        Per speed the residual correlations the tests judge (for the resid figure).
    frequency_responses : tuple of FrequencyResponseEstimate
        Per speed group and output.
    series : tuple of RunSeries
        Time series of the first :data:`SERIES_RUNS` runs (the compare figures).
    notes : tuple of str
        Remarks for the reader (e.g. K = 0: k-step prediction is a simulation).
    """

    outputs: tuple[str, ...]
    runs: tuple[str, ...]
    speeds: tuple[float, ...]
    k_step: int
    headline: str
    simulation_note: str
    fit: dict[str, float | None]
    fit_k_step: dict[str, float]
    fit_per_run: tuple[dict, ...]
    per_speed: tuple[SpeedRow, ...]
    structure: StructureCheck
    correlations: tuple[Correlations, ...]
    frequency_responses: tuple[FrequencyResponseEstimate, ...]
    series: tuple[RunSeries, ...] = ()
    notes: tuple[str, ...] = ()

    def to_json(self) -> dict:
        """The report without the time series, as plain JSON types (NaN stays a float).

        Returns
        -------
        dict
            ``fit_definition``; ``outputs``, ``runs``, ``speeds`` [m/s], ``k_step``
            [samples], ``headline``; ``fit`` and ``fit_k_step`` [%] per output;
            ``fit_per_run``; ``simulation_note``; ``per_speed`` (:meth:`SpeedRow.to_json`);
            ``residual_tests`` (the structure check's level, per-test level, rejected
            speeds, what it rejects and every test); the frequency responses
            (:meth:`FrequencyResponseEstimate.to_json`); ``bode_band``; ``notes``.
        """
        s = self.structure.to_json()
        return {
            "fit_definition": "100 (1 - ||y - yhat|| / ||y - mean y||) [%] (MATLAB compare's "
            "NRMSE fit), over all runs stacked",
            "outputs": list(self.outputs),
            "runs": list(self.runs),
            "speeds": [float(v) for v in self.speeds],
            "k_step": int(self.k_step),
            "headline": self.headline,
            "fit": dict(self.fit),
            "fit_k_step": dict(self.fit_k_step),
            "fit_per_run": [dict(d) for d in self.fit_per_run],
            "simulation_note": self.simulation_note,
            "per_speed": [r.to_json() for r in self.per_speed],
            "residual_tests": {
                "test": "ident.structure.check_structure (as bikeid identify): one-step "
                "residuals per speed, chi-squared whiteness N sum r(k)^2 and independence "
                "from T_delta N r' R_u^-1 r on lags 1..M, Bonferroni over the speeds",
                "max_lag": int(self.correlations[0].lags[-1]) if self.correlations else None,
                "rejects": self.structure.causes(),
                **{
                    k: s[k]
                    for k in ("level", "per_test_level", "n_tests", "rejected_speeds", "tests")
                },
            },  # fmt: skip
            "frequency_responses": [e.to_json() for e in self.frequency_responses],
            "bode_band": self.band_summary(),
            "notes": list(self.notes),
        }

    def band_summary(self) -> dict | None:
        """How many nonparametric points lie inside the model's 95 % Bode band.

        Returns
        -------
        dict or None
            ``level``, ``n_inside``, ``n_consistent`` and ``n_points`` over every excited
            channel and speed, ``fraction`` and ``fraction_consistent`` (None without
            points), ``calibration`` (what the band is worth:
            :data:`INTERVAL_CALIBRATION`); None when the model has no parameter covariance.
        """
        return _band_counts(self.frequency_responses, summary=True)


def _band_counts(ests: Sequence[FrequencyResponseEstimate], summary: bool = False) -> dict | None:
    """Points inside the Bode band over ``ests`` (None without a band)."""
    marks = [e.in_band for e in ests]
    n = sum(int(e.valid.sum()) for e in ests)
    if not marks or any(m is None for m in marks):
        return None if summary else {"n_points": n, "n_inside": None, "n_consistent": None,
                                     "fraction": None}  # fmt: skip
    n_in = sum(int(m.sum()) for m in marks)
    n_ok = sum(int(e.consistent.sum()) for e in ests)
    if not summary:
        return {"n_points": n, "n_inside": n_in, "n_consistent": n_ok,
                "fraction": n_in / n if n else None}  # fmt: skip
    return {"level": BAND_LEVEL, "n_inside": n_in, "n_consistent": n_ok, "n_points": n,
            "fraction": n_in / n if n else None,
            "fraction_consistent": n_ok / n if n else None,
            "calibration": INTERVAL_CALIBRATION,
            "inside_means": "magnitude [dB] and phase [deg] of the estimate both within "
            "the band's half-widths about the model's sampled response",
            "consistent_means": "the same with the band widened by the estimate's own "
            "95 % random error (in quadrature)"}  # fmt: skip


def _fits(Y: np.ndarray, Yh: np.ndarray, outputs: Sequence[str]) -> dict[str, float]:
    return {o: 100 * goodness_of_fit(Y[:, j], Yh[:, j])["nrmse_fit"] for j, o in enumerate(outputs)}


class _StackedFit:
    """NRMSE fit of all runs stacked, accumulated one block at a time.

    Sums of squared errors add; the sum of squares about the overall mean combines the
    blocks' means and sums of squares about their own means (Chan, Golub & LeVeque 1983),
    so the result equals :func:`~bikeid.ident.validate.goodness_of_fit` on the stacked
    arrays up to rounding without holding them.
    """

    def __init__(self, p: int) -> None:
        self.n, self.mean, self.m2, self.sse = 0, np.zeros(p), np.zeros(p), np.zeros(p)

    def add(self, Y: np.ndarray, Yh: np.ndarray) -> None:
        nb, mb = Y.shape[0], Y.mean(axis=0)
        m2b = ((Y - mb) ** 2).sum(axis=0)
        n = self.n + nb
        d = mb - self.mean
        self.m2 = self.m2 + m2b + d**2 * self.n * nb / n
        self.mean = self.mean + d * nb / n
        self.n = n
        self.sse = self.sse + ((Y - Yh) ** 2).sum(axis=0)

    def fit(self, outputs: Sequence[str]) -> dict[str, float]:
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(self.m2 > 0, np.sqrt(self.sse) / np.sqrt(self.m2), np.nan)
        return {o: float(100 * (1 - ratio[j])) for j, o in enumerate(outputs)}


def _speed_groups(runs: Sequence[Run]) -> dict[float, list[int]]:
    """Run indices by speed: runs within :data:`SPEED_GROUP` of a group's first speed."""
    groups: dict[float, list[int]] = {}
    for i, r in enumerate(runs):
        key = next((s for s in groups if abs(s - r.speed) <= SPEED_GROUP), r.speed)
        groups.setdefault(key, []).append(i)
    return groups


def _at_speed(model, group: Sequence[Run]):
    """A model over speed taken once at the group's speed (when its runs share one), as
    :func:`~bikeid.ident.validate.sampled_model` would take it for each run; else as is."""
    speeds = {float(r.speed) for r in group}
    if len(speeds) == 1 and hasattr(model, "at") and not isinstance(model, DirectResult):
        return model.at(speeds.pop())
    return model


def _structure(model, runs: Sequence[Run], max_lag: int, level: float) -> StructureCheck:
    """:func:`bikeid.ident.structure.check_structure` with the models ``bikeid identify``
    passes it: the model at each speed, and a model over speed as ``speed_model``."""
    from bikeid.ident.pem import SpeedCanonicalModel
    from bikeid.ident.structure import check_structure

    speeds = sorted({round(float(r.speed), 6) for r in runs})
    over_speed = hasattr(model, "at") and not isinstance(model, DirectResult)
    models = {v: model.at(v) if over_speed else model for v in speeds}
    speed_model = None
    if isinstance(model, SpeedCanonicalModel):
        speed_model = model
    elif isinstance(model, GreyboxModel) and len(model.speeds) >= 2:  # a joint fit
        speed_model = model.speed_model()
    return check_structure(runs, models, speed_model=speed_model, level=level,
                           max_lag=max_lag)  # fmt: skip


def _verdicts(check: StructureCheck, keys: Sequence[float]) -> tuple[dict | None, dict]:
    """Per output the whiteness (None if untested) and independence verdicts at ``keys``."""
    rows = [t for v in keys for t in check.tests.get(round(float(v), 6), [])]
    out: dict[str, dict] = {}
    for kind, word in (("whiteness", "white"), ("independence", "independent")):
        d = {}
        for t in rows:
            if t["kind"] == kind:
                prev = d.get(t["output"])
                if prev is None or t["p_value"] < prev["p_value"]:
                    d[t["output"]] = {word: not t["rejected"], "p_value": t["p_value"],
                                      "per_test_level": check.per_test_level}  # fmt: skip
        out[kind] = d
    return (out["whiteness"] or None), out["independence"]


def validate_model(
    model,
    runs: Run | Sequence[Run],
    k_step: int = K_STEP,
    max_lag: int = 25,
    confidence: float = 0.99,
    coherence_min: float = COHERENCE_MIN,
    ic: str | np.ndarray = "estimate",
    nperseg: int | None = None,
    series_runs: int = SERIES_RUNS,
) -> ValidationReport:
    """Validate a model on runs: compare, k-step prediction, resid and frequency response.

    The runs are taken one speed at a time (runs within :data:`SPEED_GROUP`): each group's
    simulations, predictions and residuals are reduced to fits, correlations and spectra
    before the next, so memory does not grow with the number of runs beyond the runs
    themselves.  The residual verdicts are those of
    :func:`bikeid.ident.structure.check_structure` (the test ``bikeid identify`` applies
    before it prints intervals), so identify and validate agree on the same data.

    Parameters
    ----------
    model : CanonicalModel, SpeedCanonicalModel, GreyboxModel, DirectResult or StateSpace
        The model (models over speed are taken at each run's speed).
    runs : Run or sequence of Run
        The validation data.
    k_step : int, optional
        Prediction horizon k >= 1 [samples] of the k-step comparison.
    max_lag : int, optional
        Largest lag M of the residual correlations and tests [samples].
    confidence : float, optional
        Level of the correlation bands drawn; the residual tests' family level is
        1 - confidence (the structure check's, default 1 %).
    coherence_min : float, optional
        Coherence threshold of the frequency-response estimate.
    ic : {"estimate", "zero"} or (n,) array_like, optional
        Initial state of the simulations (:func:`~bikeid.ident.validate.compare`).
    nperseg : int, optional
        Welch segment length [samples] (:func:`frequency_response_estimate`).
    series_runs : int, optional
        Keep the time series of this many runs (the first) for the compare figures.

    Returns
    -------
    ValidationReport
        Fits [%], residual tests and frequency responses, per speed and overall.

    Raises
    ------
    ValueError
        On bad arguments, or runs the model cannot be compared with (missing signals,
        another sample period).
    UntrustworthyResult
        If the model's predictor diverges over the runs (an unstable model without a noise
        model, K = 0): validate on shorter windows.  A simulation alone that diverges is
        not an error (the k-step fit is then the headline, ``simulation_note`` says why).
    """
    if isinstance(model, Run) or (isinstance(model, (list, tuple)) and model
                                  and all(isinstance(r, Run) for r in model)):  # fmt: skip
        raise InputError("validate_model(runs, model): the arguments are swapped; the model "
                         "comes first: validate_model(model, runs)")  # fmt: skip
    runs = _runs(runs)
    if not (isinstance(k_step, (int, np.integer)) and k_step >= 1):
        raise ValueError(f"k_step={k_step}: need an integer >= 1 [samples]")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence={confidence}: need a level strictly between 0 and 1")
    notes = []
    groups = _speed_groups(runs)
    outputs = None
    refused: dict[float, str] = {}
    fit_per_run: list[dict | None] = [None] * len(runs)
    series, correlations, frf, rows_fits = [], [], [], []
    for v, idx in groups.items():
        group = [runs[i] for i in idx]
        m = _at_speed(model, group)
        try:
            sim = compare(group, m, ic=ic)
        except UntrustworthyResult as exc:
            sim, refused[v] = None, str(exc)
        try:
            pred = compare(group, m, horizon=int(k_step), ic=ic)
        except UntrustworthyResult as exc:
            raise UntrustworthyResult(
                f"neither simulation nor prediction can be trusted at {v:g} m/s: {exc}"
                if sim is None
                else str(exc)
            ) from None
        if outputs is None:
            outputs = pred.outputs
            acc_sim, acc_pred = _StackedFit(len(outputs)), _StackedFit(len(outputs))
        for k, i in enumerate(idx):
            Y = np.column_stack([runs[i][o] for o in outputs])
            acc_pred.add(Y, pred.yhat[k])
            row = {"k_step": _fits(Y, pred.yhat[k], outputs), "simulation": None}
            if sim is not None:
                acc_sim.add(Y, sim.yhat[k])
                row["simulation"] = _fits(Y, sim.yhat[k], outputs)
            fit_per_run[i] = row
            if i < series_runs:
                series.append(RunSeries(_label(runs[i], i), float(runs[i].speed), runs[i].t, Y,
                                        pred.yhat[k], None if sim is None else sim.yhat[k],
                                        row))  # fmt: skip
        rows_fits.append((v, len(idx), None if sim is None else dict(sim.fit), dict(pred.fit)))
        del sim, pred
        rr = resid(group, m, input="T_delta", max_lag=max_lag, confidence=confidence)
        correlations.append(Correlations(float(v), int(sum(r.n for r in group)), rr.band,
                                         rr.lags, rr.autocorr, rr.crosscorr))  # fmt: skip
        del rr
        frf += frequency_response_estimate(group, m, coherence_min, nperseg)
    structure = _structure(model, runs, max_lag, round(1 - confidence, 12))
    per_speed = []
    for (v, n, fs, fk), idx in zip(rows_fits, groups.values(), strict=True):
        keys = sorted({round(float(runs[i].speed), 6) for i in idx})
        white, indep = _verdicts(structure, keys)
        ests = [e for e in frf if e.speed == v]
        per_speed.append(SpeedRow(float(v), n, fs, fk, white, indep, _band_counts(ests)))
    K = sampled_model(model, runs[0].dt, runs[0].speed)[3]
    if not np.any(K):
        notes.append(
            "the model has no noise model (K = 0): its k-step prediction and one-step "
            "residuals are those of a simulation (output error), and the residual test makes "
            "no whiteness verdict (the residual holds the disturbance's response, coloured by "
            "construction; ident.structure)"
        )
    fixed = getattr(model, "speed", None) if hasattr(model, "predictor") else None
    if fixed is not None:  # a fixed-speed model on runs at other speeds: say so
        tol = max(SPEED_TOLERANCE[0], SPEED_TOLERANCE[1] * fixed)
        other = sorted({round(r.speed, 3) for r in runs if abs(r.speed - fixed) > tol})
        if other:
            notes.append(
                f"the model was identified at {fixed:g} m/s; runs at {other} m/s differ by "
                f"more than {tol:g} m/s (a speed-parameterized model covers several speeds)"
            )
    notes += _frf_notes(frf)
    sim_note = ""
    if refused:
        where = "every speed"
        if len(refused) < len(groups):
            where = f"{len(refused)} of {len(groups)} speeds ({_speed_list(refused)})"
        sim_note = (f"simulation refused at {where}: {next(iter(refused.values()))}; the "
                    f"{int(k_step)}-step prediction's fit is the headline")  # fmt: skip
    return ValidationReport(
        outputs=tuple(outputs),
        runs=tuple(_label(r, i) for i, r in enumerate(runs)),
        speeds=tuple(float(r.speed) for r in runs),
        k_step=int(k_step),
        headline="k_step" if refused else "simulation",
        simulation_note=sim_note,
        fit=acc_sim.fit(outputs) if not refused else dict.fromkeys(outputs),  # percent
        fit_k_step=acc_pred.fit(outputs),
        fit_per_run=tuple(fit_per_run),
        per_speed=tuple(per_speed),
        structure=structure,
        correlations=tuple(correlations),
        frequency_responses=tuple(frf),
        series=tuple(series),
        notes=tuple(dict.fromkeys(notes)),
    )


def _speed_list(speeds) -> str:
    """``1, 3 m/s``, or for more than four ``6 speeds in 5-15 m/s`` (the structure check's
    wording, sorted)."""
    return _speeds_text(sorted(speeds))


def _frf_notes(frf: Sequence[FrequencyResponseEstimate]) -> list[str]:
    """The estimates' notes, one per channel and kind of note, naming its speeds."""
    import re

    kinds: dict[tuple[str, str, str], list[FrequencyResponseEstimate]] = {}
    for e in frf:
        if e.note:
            # the same note but for its numbers (the largest coherence) counts as one kind
            key = (e.input, e.output, re.sub(r"\(largest [^)]*\)", "", e.note))
            kinds.setdefault(key, []).append(e)
    out = []
    for (inp, o, _), es in kinds.items():
        note = es[0].note
        if len(es) > 1 and "(largest" in note:
            top = max(float(np.nanmax(e.coherence)) for e in es)
            note = re.sub(r"\(largest [^)]*\)", f"(largest {top:.2f} over these speeds)", note)
        out.append(f"{inp} -> {o} at {_speed_list([e.speed for e in es])}: {note}")
    return out


def validate_decays(
    model,
    windows: Sequence,
    channels: Sequence[str] = ("phidot", "delta"),
    max_lag: int = 25,
    confidence: float = 0.99,
) -> dict:
    """Compare and residual tests of an experiment model on measured free decays, per file.

    The validation of :func:`validate_model` for the steer-by-wire experiment model, whose
    simulation from each decay's measured initial state (``model.simulate(windows)``,
    :meth:`bikeid.ident.effects.experiment_model.ExperimentModel.simulate`, with the windows'
    attached defect corrections) is compared with the measurements: the NRMSE fit of
    :func:`~bikeid.ident.validate.goodness_of_fit` per window and channel, and the
    simulation errors' whiteness and independence from the external steer torque T_ext
    (:func:`residual_tests`, the errors of a file's windows stacked; the model has no noise
    model, so these are output-error residuals).

    Parameters
    ----------
    model : ExperimentModel
        The model (anything with ``simulate(windows)`` returning per window a dict of the
        channels).
    windows : sequence of Window
        The decays.
    channels : sequence of str, optional
        Window signals compared (default roll rate [rad/s] and steer angle [rad]).
    max_lag : int, optional
        Largest lag of the residual tests [samples].
    confidence : float, optional
        Band level; the tests' level is 1 - confidence.

    Returns
    -------
    dict
        ``fit_definition``; ``files``: per file (sorted by name) ``file``, ``speed`` [m/s],
        ``windows``, ``fit`` per channel [%] (the mean over its windows of 100 times the
        NRMSE fit, so 100 - fit is 100 times the window error of
        :func:`bikeid.ident.effects.experiment_model.window_errors`) and ``residuals``
        (:func:`residual_tests` per channel); ``fit`` per channel [%], the mean over files.
    """
    windows = list(windows)
    if not windows:
        raise ValueError("validate_decays: no windows given")
    sims = model.simulate(windows)
    files = []
    for f in sorted({w.file for w in windows}):
        idx = [i for i, w in enumerate(windows) if w.file == f]
        fit, res, u = {c: [] for c in channels}, [], []
        for i in idx:
            w, s_ = windows[i], sims[i]
            for c in channels:
                fit[c].append(100 * goodness_of_fit(getattr(w, c), s_[c])["nrmse_fit"])
            res.append(np.column_stack([getattr(w, c) - s_[c] for c in channels]))
            u.append(np.asarray(w.T_ext, float))
        files.append({
            "file": f,
            "speed": float(np.mean([windows[i].speed for i in idx])),
            "windows": len(idx),
            "fit": {c: float(np.mean(v)) for c, v in fit.items()},
            "residuals": residual_tests(res, u, channels, max_lag, confidence),
        })  # fmt: skip
    return {
        "fit_definition": "mean over a file's decay windows of 100 (1 - ||y - y_sim|| / "
        "||y - mean y||) [%] (MATLAB compare's NRMSE fit; simulation from the measured "
        "initial state); residual tests chi-squared at level 1 - confidence on the "
        "simulation errors, input T_ext",
        "files": files,
        "fit": {c: float(np.mean([f_["fit"][c] for f_ in files])) for c in channels},
    }
