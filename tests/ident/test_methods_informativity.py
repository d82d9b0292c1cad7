"""Every estimator of ``ident.methods.METHODS`` refuses data that cannot determine its model.

Cases known both ways (``dataset.linear_loop.simulate``, the linear benchmark bicycle under
the testbed's PID roll controller, 100 Hz):

- with the testbed's white steer-torque dither (1 N m) the input carries an external part
  at every frequency: every method's data are informative;
- without dither, with an unmeasured white disturbance torque, the logged torque is the
  controller's law of the measured states (a known construction: R^2 = 1 to rounding,
  tests/ident/test_informativity.py), so no method may return a model;
- a single sinusoidal roll reference: one frequency, order of excitation 2 (MATLAB's
  ``pexcit`` of a sinusoid), fewer than any method's parameters.

The free-parameter counts are Moore & Hubbard's entry sets (3 roll + 6 steer entries, the
lateral-force entry HdF only when a run logs a force, ``ident.direct.MOORE_ROLL`` /
``MOORE_STEER``) and Chen & Dao's canonical parameters (a1-a8, b1, b2; over speed the odd
a's as alpha + beta v^2 and the even a's as gamma v: 4 + 4 + 4, plus b1, b2).
"""

from __future__ import annotations

import numpy as np
import pytest

from bikeid.dataset.linear_loop import simulate
from bikeid.ident.methods import (
    METHODS,
    SKIPPED_NOTE,
    DirectSettings,
    GreyboxSettings,
    PemSettings,
    check_informativity,
    fit_pem,
)
from bikeid.sim.errors import InputError, UntrustworthyResult
from bikeid.sim.parameters import benchmark

P = benchmark()


@pytest.fixture(scope="module")
def dithered():
    """Dithered closed loops at 3 and 5 m/s, 20 s (informative)."""
    return [simulate(P, v, duration=20.0, seed=i, dither=1.0, rate_noise=1e-3)
            for i, v in enumerate((3.0, 5.0))]  # fmt: skip


@pytest.fixture(scope="module")
def feedback():
    """The same loops without dither, disturbed by an unmeasured torque (feedback only)."""
    return [simulate(P, v, duration=20.0, seed=i + 5, dither=0.0, disturbance=0.5,
                     rate_noise=1e-3) for i, v in enumerate((3.0, 5.0))]  # fmt: skip


WHAT = {"pem": "the canonical PEM model at 3 m/s", "greybox": "the grey-box model",
        "direct": "the direct least-squares model"}  # fmt: skip


@pytest.mark.parametrize("name", list(METHODS))
def test_every_method_refuses_feedback_only_runs(name, feedback):
    """No estimator of the table returns a model from feedback-only runs: the refusal
    names the model (per-speed PEM: its speed), the cause and the fix."""
    m = METHODS[name]
    with pytest.raises(UntrustworthyResult, match=f"the logs cannot determine {WHAT[name]}: "
                       "the input T_delta is feedback only.*external steer-torque dither"):
        m.fit(feedback, m.settings(), reference=P)


@pytest.mark.parametrize("name", list(METHODS))
def test_every_method_refuses_a_single_sinusoid(name):
    """A 0.7 Hz roll reference without dither or noise, 30 s (the case of
    tests/ident/test_informativity.py): 1 frequency, order 2 < every model's parameters."""
    run = simulate(P, 5.0, duration=30.0, seed=1, dither=0.0,
                   reference=lambda t: 0.02 * np.sin(2 * np.pi * 0.7 * t))  # fmt: skip
    m = METHODS[name]
    with pytest.raises(UntrustworthyResult, match="excites 1 distinct frequency.*more "
                       "frequencies"):  # fmt: skip
        m.fit([run], m.settings(), reference=P)


@pytest.mark.parametrize(("settings", "free", "n"), [
    (PemSettings(), None, 10),                         # a1-a8, b1, b2 per speed
    (PemSettings(speed_parameterized=True), None, 14),  # alpha, beta, gamma x 4, b1, b2
    (GreyboxSettings(), None, 8),                      # Moore & Hubbard's 9 minus HdF
    (GreyboxSettings(), ("Mpd", "K0dd"), 2),
    (GreyboxSettings(mode="per_speed"), None, 7),      # per run: K2dd fixed as well
    (DirectSettings(), None, 8),
    (DirectSettings(iv="lagged"), ("Mdd", "K0dd", "K2dd"), 3),
])  # fmt: skip
def test_the_record_travels_with_the_fit(settings, free, n, dithered):
    """Dithered runs pass; the record counts the model's free parameters from its settings
    (numbers in the module docstring) and is filed per speed, per run or once."""
    rec = check_informativity(dithered, settings, free=free)
    infos = list(rec.get("per_speed", rec.get("per_run", {None: rec})).values())
    assert all(i["informative"] and i["n_params"] == n for i in infos)
    per = isinstance(settings, PemSettings) and not settings.speed_parameterized
    assert list(rec.get("per_speed", {})) == ([3.0, 5.0] if per else [])
    by_run = isinstance(settings, GreyboxSettings) and settings.mode == "per_speed"
    assert list(rec.get("per_run", {})) == ([0, 1] if by_run else [])


def test_a_fit_carries_its_record_and_skip_or_report_is_recorded(dithered, feedback):
    """The informative fit carries the assessment; ``informativity="report"`` fits
    feedback-only data but records the cause; ``"skip"`` records that nothing was checked
    (never silent); an unknown choice is refused."""
    ok = fit_pem(dithered[:1])
    assert ok.informativity["per_speed"][3.0]["informative"]
    rep = fit_pem(feedback[:1], informativity="report")
    info = rep.informativity["per_speed"][3.0]
    assert not info["informative"] and "feedback only" in info["cause"]
    assert info["r2"][0] > 0.9999  # the controller's law of the measured states
    skip = fit_pem(feedback[:1], informativity="skip")
    assert skip.informativity == {"skipped": True, "note": SKIPPED_NOTE}
    assert len(skip.models) == 1
    with pytest.raises(InputError, match="informativity='no': choose one of refuse, report"):
        fit_pem(dithered[:1], informativity="no")


def test_model_over_speed_needs_excited_runs_at_two_speeds(dithered, feedback):
    """One dithered run at 3 m/s and a feedback-only one at 5 m/s: per-speed PEM is refused
    at 5 m/s (named), the model over speed because only 3 m/s carries excitation."""
    runs = [dithered[0], feedback[1]]
    with pytest.raises(UntrustworthyResult, match="canonical PEM model at 5 m/s: the input "
                       "T_delta is feedback only"):  # fmt: skip
        fit_pem(runs)
    with pytest.raises(UntrustworthyResult, match="speed-parameterized PEM model: only the "
                       "runs at 3 m/s carry excitation"):  # fmt: skip
        fit_pem(runs, PemSettings(speed_parameterized=True))


def _lower(name: str, runs, **kw):
    """The estimators under the table, as the docs call them."""
    from bikeid.ident import direct, greybox, pem

    if name == "pem.fit":
        return pem.fit(runs[:1], **kw)
    if name == "pem.fit_speed_model":
        return pem.fit_speed_model(runs, **kw)
    if name == "greybox.fit":
        return greybox.fit(runs, ("Mpd", "K0pd", "Mdd", "K0dd", "K2dd"), P, **kw)
    return direct.identify(runs, reference=P, **kw)


LOWER = ["pem.fit", "pem.fit_speed_model", "greybox.fit", "direct.identify"]


@pytest.mark.parametrize("name", LOWER)
def test_the_estimators_the_docs_call_refuse_too(name, feedback):
    """``pem.fit`` (the README's example), ``pem.fit_speed_model``, ``greybox.fit`` and
    ``direct.identify`` refuse feedback-only runs by themselves, before any fit."""
    with pytest.raises(UntrustworthyResult, match="the logs cannot determine .*feedback only"):
        _lower(name, feedback)


@pytest.mark.parametrize("name", LOWER)
def test_the_estimators_the_docs_call_record_report_and_skip(name, feedback, dithered):
    """Asked to fit anyway, each says so in the model's notes: the cause, or that the
    check was skipped; informative data add no note."""
    rep = _lower(name, feedback, informativity="report")
    assert any("the logs cannot determine" in n and "feedback only" in n for n in rep.notes)
    skip = _lower(name, feedback, informativity="skip")
    assert SKIPPED_NOTE in skip.notes
    ok = _lower(name, dithered)
    assert not any("informativity" in n or "cannot determine" in n for n in ok.notes)
