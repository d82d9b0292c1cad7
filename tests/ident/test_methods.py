"""ident.methods: one table of identification methods, a name means one estimator everywhere.

Truths: the benchmark bicycle's linearization (Meijaard 2007, ``sim.linear``) for the fits
on noise-free closed-loop data, and the estimators' own primitives
(``ident.signals.prepare`` + ``ident.direct.identify``, ``ident.pem.fit``,
``ident.greybox.fit``) called directly for the dispatch: the table must run exactly them.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from bikeid.dataset.importers import from_arrays
from bikeid.dataset.linear_loop import simulate
from bikeid.dataset.run import Run
from bikeid.ident import greybox, pem
from bikeid.ident.direct import identify
from bikeid.ident.methods import (
    DIRECT_PRESETS,
    METHODS,
    DirectSettings,
    GreyboxSettings,
    Identified,
    PemSettings,
    method,
)
from bikeid.ident.model_file import KINDS
from bikeid.ident.signals import prepare
from bikeid.sim.errors import InputError
from bikeid.sim.linear import eigenvalues
from bikeid.sim.parameters import benchmark

P = benchmark()
SPEEDS = (3.0, 5.0)


@pytest.fixture(scope="module")
def runs():
    """Noise-free closed-loop runs (PID, 1 N m dither), 20 s at two speeds."""
    return [simulate(P, v, duration=20.0, seed=i, dither=1.0) for i, v in enumerate(SPEEDS)]


def _identify_parser() -> argparse.ArgumentParser:
    from bikeid.experiments.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return sub.choices["identify"]


def test_table_is_the_one_list_of_methods():
    """The CLI's --method choices and the model loader's kinds are the table's."""
    ident = _identify_parser()
    choices = next(a.choices for a in ident._actions if a.dest == "method")
    assert tuple(choices) == tuple(METHODS) or set(choices) == set(METHODS)
    for m in METHODS.values():
        assert len(m.kinds) == len(m.model_classes)
        for kind, cls in zip(m.kinds, m.model_classes, strict=True):
            assert KINDS[kind] is cls
    with pytest.raises(InputError, match="choose one of pem, greybox, direct"):
        method("subspace")


def test_cli_defaults_are_the_settings_defaults():
    """``--help`` shows the defaults the settings dataclass states (one place)."""
    ident = _identify_parser()
    defaults = {a.dest: a.default for a in ident._actions}
    assert defaults["derivative"] == DirectSettings.derivative
    assert defaults["cutoff"] is DirectSettings.cutoff_hz  # None: 3 Hz interval, else 15 Hz
    assert defaults["iv"] is False and DirectSettings.iv is None
    assert defaults["speed_parameterized"] is PemSettings.speed_parameterized
    assert defaults["drop_unidentifiable"] is GreyboxSettings.drop_unidentifiable


def test_direct_settings_resolve_describe_and_refuse():
    assert DirectSettings().cutoff == 3.0 and DirectSettings(derivative="central").cutoff == 15.0
    assert DirectSettings(cutoff_hz=0.0).describe().endswith("no low-pass")
    assert DIRECT_PRESETS["unfiltered"].describe() == (
        "least squares, central differences, no low-pass, means kept")
    mh = DIRECT_PRESETS["moore-hubbard"]
    assert (mh.derivative, mh.cutoff, mh.iv) == ("central", 15.0, None)
    assert mh.describe() == "least squares, central differences, 15 Hz low-pass"
    assert DirectSettings.from_options({"iv": True, "derivative": "forward"}) == DirectSettings(
        derivative="forward", iv="lagged"
    )
    assert DirectSettings.from_options({"preset": "moore-hubbard"}) == mh
    for bad in ({"derivative": "spline"}, {"cutoff_hz": -1.0}, {"iv": "magic"}, {"lags": 0}):
        with pytest.raises(InputError):
            DirectSettings(**bad)
    for bad in ({"lags": float("inf")}, {"lags": "x"}):
        with pytest.raises(InputError, match="lags=.*whole number"):
            DirectSettings(**bad)
    # options from a file or a caller: a misspelt preset or a non-number is one line
    with pytest.raises(InputError, match="preset='nope': choose one of default, moore-hubbard"):
        DirectSettings.from_options({"preset": "nope"})
    with pytest.raises(InputError, match="cutoff='abc': give a frequency"):
        DirectSettings.from_options({"cutoff": "abc"})


@pytest.mark.parametrize("preset", sorted(DIRECT_PRESETS))
def test_direct_is_one_estimator_whatever_calls_it(runs, preset):
    """The table's direct fit with a preset is exactly prepare + identify with those
    settings, bit for bit: no caller has its own variant of 'direct'."""
    s = DIRECT_PRESETS[preset]
    got = METHODS["direct"].fit(runs, s, reference=P)
    if s.iv == "tailored":
        pytest.skip("no tailored preset")
    if not s.remove_means:  # the logged signals as they are: identify's own differences
        assert (s.cutoff, s.derivative) == (0.0, "central")
        ref = identify(runs, P)
    else:
        ref = identify([prepare(r, cutoff=s.cutoff or None, derivative=s.derivative)
                        for r in runs], P, method="ls" if s.iv is None else "iv",
                       instruments=s.iv or "lagged", lags=s.lags,
                       covariance=s.covariance)  # fmt: skip
    (model,) = got.models
    for k in ("M", "C1", "K0", "K2", "H"):
        np.testing.assert_array_equal(getattr(model, k), getattr(ref, k))
    assert got.settings == s and got.details["free"].keys() == ref.free.keys()


def test_pem_and_greybox_are_their_estimators(runs):
    """The table's pem/greybox fits equal the estimators called directly (same starts)."""
    got = METHODS["pem"].fit(runs)
    per, prev = {}, None
    for r in runs:
        prev = per[r.speed] = pem.fit(r, starts=() if prev is None else (prev.theta,))
    for m, v in zip(got.models, SPEEDS, strict=True):
        np.testing.assert_array_equal(m.theta, per[v].theta)
    gb = METHODS["greybox"].fit(runs, reference=P)
    np.testing.assert_array_equal(gb.models[0].M, greybox.fit(runs, None, P).M)


@pytest.mark.parametrize("name", list(METHODS))
def test_every_method_recovers_noise_free_truth(runs, name):
    """Noise-free dithered closed loop: PEM and grey-box (exact model structure, exact ZOH
    data) recover the eigenvalues to round-off of a converged fit (observed 7e-13 relative;
    tolerance 1e-8).  Direct (interval-averaged equation, exact up to O(dt^2), then a 3 Hz
    zero-phase filter whose start/end transients the 20 s runs do not average away): observed
    3.9 %; tolerance 6 % (the accuracy study's 2 % needs the 50 s runs of ``bikeid accuracy``)."""
    res = METHODS[name].fit(runs, reference=P)
    assert isinstance(res, Identified) and res.method == name
    assert all(isinstance(m, METHODS[name].model_classes) for m in res.models)
    assert res.speeds == SPEEDS
    tol = 0.06 if name == "direct" else 1e-8
    for v in SPEEDS:
        truth = np.sort_complex(eigenvalues(P, v))
        ev = res.eigenvalues(v)
        err = np.abs(np.asarray(ev) - truth) / np.maximum(np.abs(truth), 1.0)
        assert err.max() < tol, (name, v, err)
        assert sorted(ev.modes) == ["capsize", "caster", "weave", "weave"]
    json.dumps(res.settings.to_json())  # the settings saved with the model are plain JSON


def test_speed_parameterized_pem_needs_two_speeds(runs):
    with pytest.raises(InputError, match="two or more speeds"):
        METHODS["pem"].fit(runs[:1], PemSettings(speed_parameterized=True))
    res = METHODS["pem"].fit(runs, PemSettings(speed_parameterized=True))
    assert len(res.models) == 1 and res.speed_model is res.models[0]
    assert not METHODS["pem"].one_file_per_speed(res.settings)


def _as_users_arrays(run: Run) -> Run:
    """The run as a user's logger has it: own names, degrees, ms, km/h, roll positive left."""
    users = {"roll_deg": -np.degrees(run["phi"]), "steer_deg": np.degrees(run["delta"]),
             "roll_rate": -np.degrees(run["phidot"]), "steer_rate": np.degrees(run["deltadot"]),
             "torque": run["T_delta"], "kmh": run["v"] * 3.6}  # fmt: skip
    mapping = {"phi": "roll_deg", "delta": "steer_deg", "phidot": "roll_rate",
               "deltadot": "steer_rate", "T_delta": "torque", "v": "kmh"}  # fmt: skip
    units = {"t": "ms", "phi": "deg", "delta": "deg", "phidot": "deg/s", "deltadot": "deg/s",
             "v": "km/h"}  # fmt: skip
    return from_arrays(run.t * 1000.0, users, mapping, units, flip=["phi", "phidot"],
                           meta={"parameters": run.meta["parameters"]})  # fmt: skip


@pytest.mark.parametrize("name", list(METHODS))
def test_every_estimator_accepts_the_data_object(runs, name):
    """A Run built from a user's arrays (own names, deg, ms, km/h, flipped roll) gives the
    same model as the original run: the conversions differ from the original by rounding
    (deg -> rad and back, ~1e-16 relative), which a converged fit passes on unamplified
    (tolerance 1e-8 relative on the eigenvalues)."""
    users = [_as_users_arrays(r) for r in runs]
    assert users[0].dt == pytest.approx(runs[0].dt, rel=1e-12)
    a = METHODS[name].fit(runs, reference=P)
    b = METHODS[name].fit(users, reference=P)
    for v in SPEEDS:
        np.testing.assert_allclose(np.asarray(b.eigenvalues(v)), np.asarray(a.eigenvalues(v)),
                                   rtol=1e-8, atol=1e-8)  # fmt: skip


def test_identify_prints_and_saves_the_settings_it_ran(runs, tmp_path, capsys):
    """Every identify run names its settings (text and JSON) and stores them in the model file."""
    from bikeid.dataset.store import write_runs
    from bikeid.experiments.cli import main
    from bikeid.ident.model_file import read_model_file

    path = tmp_path / "runs.h5"
    write_runs(path, runs)
    out = tmp_path / "direct.json"
    code = main(["identify", str(path), "--method", "direct", "--derivative", "central",
                 "--out", str(out), "--quiet", "--skip-check", "informativity"])  # fmt: skip
    text = capsys.readouterr().out
    assert code == 0
    assert "settings: least squares, central differences, 15 Hz low-pass" in text
    saved = read_model_file(out).settings
    assert (saved["derivative"], saved["cutoff"], saved["iv"]) == ("central", 15.0, None)
    assert main(["identify", str(path), "--method", "pem", "--json", "--quiet",
                 "--skip-check", "informativity"]) == 0  # fmt: skip
    doc = json.loads(capsys.readouterr().out)
    assert doc["settings"]["description"] == PemSettings().describe()
    assert [r["modes"] for r in doc["per_speed"]] == [
        list(METHODS["pem"].fit(runs).eigenvalues(v).modes) for v in SPEEDS
    ]


def test_every_caller_names_its_direct_settings():
    """accuracy's rows and the reproductions run the table's direct with named settings: the
    IV row is the testbed preset, the least-squares row and both reproductions are Moore &
    Hubbard's published processing (central differences, 15 Hz)."""
    from bikeid.experiments.papers import chen_dao, moore_hubbard
    from bikeid.experiments.testbed import accuracy as acc

    assert acc.row_settings("direct") == DIRECT_PRESETS["testbed-iv"]
    assert acc.row_settings("direct_ls") == DIRECT_PRESETS["moore-hubbard"]
    mh = DIRECT_PRESETS["moore-hubbard"]
    assert (moore_hubbard.CUTOFF_HZ, moore_hubbard.DERIVATIVE) == (mh.cutoff, mh.derivative)
    assert chen_dao.DIRECT_DERIVATIVE == mh.derivative
    from bikeid.experiments.measured import study

    assert study.DIRECT_SETTINGS == DIRECT_PRESETS["unfiltered"]
    for row in acc.METHODS:
        assert isinstance(acc.row_settings(row), METHODS[{"direct_ls": "direct"}.get(
            row, row)].settings_type)  # fmt: skip
