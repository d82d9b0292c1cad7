"""Can the data determine the model?  ``ident.informativity`` on cases known both ways.

Simulated closed loops of the linear benchmark bicycle under the testbed's PID roll
controller (``dataset.linear_loop.simulate``), 30 s at 100 Hz:

- with the testbed's white steer-torque dither (1 N m, held one sample, or 10 samples) the
  plant is identifiable (the dither is an external input independent of the states); the
  canonical PEM model has 10 parameters;
- without dither and with an unmeasured white disturbance torque, the logged torque is the
  controller's law of the measured states (PI on roll plus D on the roll rate), so a state
  law reproduces it to rounding (R^2 = 1) and the data show the closed loop only;
- with a single sinusoidal roll reference and no noise, the input holds one frequency
  (order of excitation 2, MATLAB's ``pexcit`` of a sinusoid), fewer than 10 parameters need.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.dataset.linear_loop import simulate
from bikeid.ident.informativity import (
    FEEDBACK_R2,
    assess,
    check,
    excited_frequencies,
    feedback_share,
    tone_bins,
)
from bikeid.sim.errors import InputError, UntrustworthyResult
from bikeid.sim.parameters import benchmark


def _const_run(u):
    """A run whose input is ``u`` and whose states do not move with it (white noise)."""
    from bikeid.dataset.run import Run

    rng = np.random.default_rng(0)
    sig = {k: rng.normal(0, 1e-3, u.size) for k in ("phi", "delta", "phidot", "deltadot")}
    return Run(t=np.arange(u.size) * 0.01, signals={**sig, "v": np.full(u.size, 5.0),
                                                    "T_delta": u})  # fmt: skip


def _loop(**kw):
    return simulate(benchmark(), 5.0, duration=30.0, seed=kw.pop("seed", 1), **kw)


@pytest.mark.parametrize("hold", [1, 10])
def test_dithered_loop_is_informative(hold):
    """The testbed's dither: the state law leaves most of the torque unexplained (observed
    R^2 0.40 and 0.83, below the 0.9 that FEEDBACK_R2's comment states for dithered runs,
    itself below the 0.98 threshold) and its residual excites hundreds of frequencies, far
    above the 10 parameters of the canonical model."""
    run = _loop(dither=1.0, dither_hold=hold, rate_noise=1e-3, angle_noise=1e-4)
    info = check([run], 10, what="the canonical PEM model")
    assert info.informative and info.r2[0] < 0.9 < FEEDBACK_R2
    assert info.order >= 10 and info.input_order >= 10


def test_loop_without_dither_is_feedback_only():
    """No dither: T = Kp (r - phi) + Ki int(r - phi) - Kd phidot of the measured states, so
    the state law (with the integrals of the angles) reproduces it: R^2 = 1 to rounding."""
    run = _loop(dither=0.0, disturbance=0.5, rate_noise=1e-3, angle_noise=1e-4)
    r2, res = feedback_share(run)
    assert r2 > 0.9999
    with pytest.raises(UntrustworthyResult, match="cannot determine the canonical PEM model: "
                       "the input T_delta is feedback only.*dither"):  # fmt: skip
        check([run], 10, what="the canonical PEM model")


def test_single_sinusoid_is_refused_as_one_frequency():
    """A 0.7 Hz roll reference and no noise: one frequency, order 2 < 10."""
    run = _loop(dither=0.0, reference=lambda t: 0.02 * np.sin(2 * np.pi * 0.7 * t))
    info = assess([run], 10)
    assert info.input_order == 2
    assert "excites 1 distinct frequency (order of excitation 2" in info.cause
    assert "fit at most 2 free parameters" in info.cause  # the remedy, followed next line
    with pytest.raises(UntrustworthyResult, match="more frequencies"):
        check([run], 10)
    assert assess([run], 2).informative  # two parameters: one sinusoid suffices


def test_multisine_counts_its_frequencies():
    """A sum of k sinusoids at well-separated frequencies (1 Hz apart over 30 s, 30 bins)
    is k distinct frequencies: order 2k (pexcit of a multisine)."""
    t = np.arange(3000) * 0.01
    for k in (1, 3, 6):
        u = sum(np.sin(2 * np.pi * (0.5 + j) * t + j) for j in range(k))
        info = assess([_const_run(u)], 2 * k)
        assert info.input_order == 2 * k, (k, excited_frequencies(u, 0.01))


@settings(max_examples=20, deadline=None)
@given(st.floats(0.2, 20.0), st.floats(0.0, 6.0))
def test_one_tone_is_one_frequency(freq, phase):
    """Any single tone within the band, on or between bins, counts as one frequency (the
    tone width of ``tone_bins`` is the largest over bin offsets)."""
    t = np.arange(4000) * 0.01
    f = excited_frequencies(np.sin(2 * np.pi * freq * t + phase), 0.01)
    assert 1 <= len(f) <= tone_bins(4000)


def test_pooled_runs_need_excited_speeds():
    """A model over speed from one dithered run and one feedback-only run at another
    speed: the excited runs cover one speed, so a model over speed is refused; the same
    runs pass when the model needs one speed only."""
    good = _loop(dither=1.0, rate_noise=1e-3)
    bad = simulate(benchmark(), 6.0, duration=30.0, seed=2, dither=0.0, disturbance=0.5)
    info = assess([good, bad], 8, min_speeds=2)
    assert info.feedback_only == (1,)
    assert "only the runs at 5 m/s carry excitation" in info.cause
    assert assess([good, bad], 8, min_speeds=1).informative


def test_bad_arguments():
    run = _loop(dither=1.0)
    with pytest.raises(InputError):
        assess([], 10)
    with pytest.raises(InputError):
        assess([run], 0)
    with pytest.raises(InputError):
        assess([run], 10, threshold=1.5)


# -- the threshold on the steer-by-wire push logs (FEEDBACK_R2's comment) ----------------
DATA = os.environ.get("BIKEID_DATA")
needs_data = pytest.mark.skipif(
    not DATA or not Path(DATA, "tudelft-sbw", "eigen").is_dir(),
    reason="set BIKEID_DATA to the folder holding tudelft-sbw/ (the measured logs)",
)


def _push_log(kph: str):
    from bikeid.dataset.sbw_logs import data_dir, load_log, settled

    return settled(load_log(data_dir(DATA) / "eigen" / f"eigen_normal_sil6.5n2_{kph}kph.log.gz"))


@needs_data
@pytest.mark.parametrize("kph", ["5.4", "12.6", "16.2"])
def test_push_logs_are_refused_as_feedback(kph):
    """The push logs at 1.5, 3.5, 4.5 m/s: the logged command is the balance law
    K (V - v) phidot (the data README), which the state law reproduces to >= 0.995 (measured
    1.0000, 0.9987, 0.9951; the remainder is a few relayed handlebar bursts), so no model."""
    run = _push_log(kph)
    with pytest.raises(UntrustworthyResult, match="the input T_delta is feedback only") as err:
        check([run], 10, what="the canonical PEM model")
    # the fix that applies to free decays: measured fit (followed on these logs by
    # tests/ident/effects/test_pipeline.py); never "fewer free entries", which cannot help
    assert "bikeid measured fit" in str(err.value) and "--free" not in str(err.value)
    assert assess([run], 10).r2[0] >= 0.995


@needs_data
def test_push_log_at_9_kmh_is_a_known_limit():
    """The 9 km/h push log passes the feedback share (0.8994), and that is what the data
    give, not a defect of the law: its balance-law part (``sil_command``) is reproduced to
    rounding (R^2 > 0.9999, the README's law K (V - v) phidot), while its plant input
    ``command_fork`` also holds the relayed handlebar torque (``command_fork - sil_command``
    correlates > 0.9 with ``hand_torque``: measured 0.91), which no state law reproduces.
    Its R^2 lies between the testbed's dithered runs (<= 0.83) and a small-dither run
    that determines the model (0.968), so no threshold separates it (FEEDBACK_R2's comment).
    """
    run = _push_log("9")
    assert feedback_share(run, "sil_command")[0] > 0.9999
    assert np.corrcoef(run["T_ext"], run["hand_torque"])[0, 1] > 0.9
    r2 = feedback_share(run)[0]
    assert 0.85 < r2 < FEEDBACK_R2  # measured 0.8994
    assert assess([run], 10).informative
    assert _lagged_law_r2(run) < 0.85  # a low-order dynamic law does not reproduce it: 0.680


def _lagged_law_r2(run, lags: int = 3) -> float:
    """Held-out R^2 of the static law plus the four states lagged 1..``lags`` samples:
    least squares on the first half, judged on the second (a second construction of a
    low-order dynamic law, independent of ``feedback_share``)."""
    from bikeid.ident.informativity import _law

    cols = [_law(run, "T_delta")]
    for s in ("phi", "delta", "phidot", "deltadot"):
        x = np.asarray(run[s], float)
        cols += [np.concatenate([np.full(k, x[0]), x[:-k]])[:, None] for k in range(1, lags + 1)]
    X, u = np.hstack(cols), np.asarray(run["T_delta"], float)
    h = run.n // 2
    coef, *_ = np.linalg.lstsq(X[:h], u[:h], rcond=None)
    res = u[h:] - X[h:] @ coef
    return float(1.0 - np.sum(res**2) / np.sum((u[h:] - u[h:].mean()) ** 2))


def test_a_lagged_law_would_refuse_the_testbeds_own_dithered_run():
    """Why the law has no lagged states: on the testbed's dithered sweep run (pole placement
    at 2 m/s, the sweep's defaults: roll chirp and a dither held 0.05 s) the static law
    leaves a third of the torque unexplained (R^2 0.633), but with the states lagged 1-3
    samples a law reproduces 0.974 of it on the held-out second half (the lags give back
    the held input through the plant's equation), far above what the 9 km/h push log
    reaches with the same law (0.680): a lagged law would refuse this run first.  The
    bounds 0.8 and 0.95 sit between the two measured values and the threshold's other
    cases (FEEDBACK_R2's comment)."""
    from bikeid.experiments.testbed.sweep import SweepSpec, Task, simulate_task

    run = simulate_task(SweepSpec(controller="pole", speeds=(2.0,)), Task("pole", 2.0, 0))
    assert feedback_share(run)[0] < 0.8
    assert _lagged_law_r2(run) > 0.95
    assert check([run], 10).informative
