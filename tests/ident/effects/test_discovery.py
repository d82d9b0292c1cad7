"""Discovery of a term the equations of motion lack (``ident.effects.discovery``).

Independent sources: the units derived by hand from torque / signal / v^p (not from the law
language's unit table); the truth injected by construction into the project's linear
generator (``synthetic_decays``) through an effects file; decays of the nominal model with
no term added (the answer is known to be empty).
"""

from __future__ import annotations

import argparse

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.ident.effects.discovery import dictionary, discover, injection_file, term_by_name
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.effects.synthetic_decays import synthetic_windows
from bikeid.sim.effect_files import load_effects_file, read_effects_file
from bikeid.sim.effect_law import parse_law, unit_dimensions
from bikeid.sim.effect_registry import EFFECTS, unregister_effects

# (kg, m, s, rad) of each signal, by hand: an angle is rad, a rate rad/s, an acceleration
# rad/s^2, a sign or the constant dimensionless, the steer torque N m = kg m^2 s^-2
_SIGNAL = {"phi": (0, 0, 0, 1), "delta": (0, 0, 0, 1), "phidot": (0, 0, -1, 1),
           "deltadot": (0, 0, -1, 1), "phiddot": (0, 0, -2, 1), "deltaddot": (0, 0, -2, 1),
           "sign(phidot)": (0, 0, 0, 0), "sign(deltadot)": (0, 0, 0, 0), "1": (0, 0, 0, 0),
           "T": (1, 2, -2, 0)}  # fmt: skip
_TORQUE = np.array((1, 2, -2, 0))  # N m
_SPEED = np.array((0, 1, -1, 0))  # m/s
# the brief's list, by hand: each state and T, the states times v, v^2 and 1/v, the two
# accelerations, the sign of each rate, a constant
_STATES = ("phi", "delta", "phidot", "deltadot")
_TERMS = {*_STATES, *(f"v*{s}" for s in _STATES), *(f"v^2*{s}" for s in _STATES),
          *(f"{s}/v" for s in _STATES), "T", "phiddot", "deltaddot", "sign(phidot)",
          "sign(deltadot)", "1"}  # fmt: skip
_POWER = {"v*": 1, "v^2*": 2}


def _hand_dims(term: str) -> tuple[int, ...]:
    """Torque over the term's unit: N m / (signal * v^p), derived from the text."""
    p, s = 0, term
    for prefix, q in _POWER.items():
        if s.startswith(prefix):
            p, s = q, s.removeprefix(prefix)
    if s.endswith("/v"):
        p, s = -1, s.removesuffix("/v")
    dims = _TORQUE - np.array(_SIGNAL[s]) - p * _SPEED
    if s in ("phiddot", "deltaddot"):  # the registry writes an inertia kg m^2 (rad dropped)
        dims[3] = 0
    return tuple(int(x) for x in dims)


def test_dictionary_is_the_briefs_terms_with_hand_derived_units():
    """44 terms, 22 per equation, exactly the listed ones; each term's unit has the
    dimensions of N m / (signal v^p) derived by hand (e.g. roll: v*phidot: N m s^2 / (rad
    m)); the sign convention: the injected ``roll: phidot`` coefficient -3 is the built-in
    roll damping's value +3 in ``roll: -c * phidot``, and an injected ``steer: v*phi`` of +0.5
    adds -0.5 v to K[steer, roll] on the left side (torque +0.5 v phi on the right)."""
    d = dictionary()
    assert len(d) == 44
    for eq in ("roll", "steer"):
        assert {t.term for t in d if t.equation == eq} == _TERMS
    for t in d:
        assert unit_dimensions(t.unit) == _hand_dims(t.term), (t.label, t.unit)
    assert term_by_name("roll: phidot").reading == "roll viscous damping"
    damping = term_by_name("roll: phidot")
    assert damping.entry == "roll_viscous_damping" and damping.value(-3.0) == 3.0
    assert [t.label for t in d if t.no_closure] == ["roll: T"]


@settings(max_examples=60, deadline=None)
@given(i=st.integers(0, 43), c=st.floats(-1e4, 1e4, allow_nan=False))
def test_coefficient_and_entry_value_are_inverse_and_laws_reparse(i, c):
    """For any term and coefficient, the entry value maps back to the coefficient (to
    rounding), and the term's law text parses back to the same term (the language's own
    parser: the dictionary writes only what the language reads)."""
    t = dictionary()[i]
    assert t.coefficient(t.value(c)) == pytest.approx(c, rel=1e-12, abs=1e-12)
    if t.law.kind != "torque":
        assert parse_law(t.law.text()).key == t.law.key
        assert term_by_name(t.label).label == t.label


def test_an_injected_term_is_what_the_generator_simulates(tmp_path):
    """The effects file of :func:`injection_file` (a term with no built-in entry) makes the
    experiment model add the torque coefficient * term: +0.5 N m s/(rad m) * v * phi on the
    steer row is -0.5 v in the stiffness matrix's [steer, roll] entry at v = 3 m/s (exact)."""
    f = load_effects_file(injection_file(tmp_path / "inj.yaml", {"steer: v*phi": 0.5}))
    try:
        m = ExperimentModel(effects=dict(f.values))
        assert f.names == ("steer_v_phi",)
        assert m.law_matrix("angle", 3.0)[1, 0] == pytest.approx(-1.5, rel=1e-12)
        assert np.count_nonzero(m.law_matrix("angle", 3.0)) == 1
    finally:
        unregister_effects(f.names)


@pytest.fixture(scope="module")
def damped(tmp_path_factory):
    """Discovery on the project's generator with an injected roll viscous damping (torque
    -3 N m s/rad * phidot, outside the library), 2 speeds x 4 decays, 0.005 rad/s noise,
    seed 0; and on the same generator without it."""
    path = tmp_path_factory.mktemp("inj") / "roll_damping.yaml"
    f = load_effects_file(injection_file(path, {"roll: phidot": -3.0}))
    try:  # the file's entry registered while the generator simulates it
        truth = ExperimentModel(effects=dict(f.values))
        ws = synthetic_windows(truth, [2.0, 3.5], 4, noise=0.005, seed=0)
    finally:
        unregister_effects(f.names)
    quiet = synthetic_windows(ExperimentModel(), [2.0, 3.5], 4, noise=0.005, seed=0)
    from bikeid.ident.effects.acceptance import AcceptanceRule

    exact = AcceptanceRule.exact()  # the generator's bicycle is the stated one (the rates)
    return discover(ExperimentModel(), ws, rule=exact), discover(ExperimentModel(), quiet,
                                                                 rule=exact)  # fmt: skip


def test_injected_roll_damping_is_found_and_no_effect_decays_give_nothing(damped):
    """With the damping: one term, roll: phidot or a term whose indistinguishable set holds
    it (a damping growing or falling with v: 8 decays at 2 speeds cannot always tell them
    apart), roll: phidot's coefficient within 35 % of -3 and its 95 % interval covering -3.
    Without it: an empty list (126 tests at 0.05 / 126).  Rates of this set-up on seeds 0-9
    (development seeds, ``benchmarks/bench_discovery.py``): roll: phidot kept or in the kept
    term's set with nothing extra in 9 of 10 (seed 6: nothing kept), within 35 % in 9, its
    interval covering -3 in 8; no-effect seeds 0-19: nothing kept in 20 of 20.  Seed 0 is
    the first of them, not chosen for passing."""
    found, quiet = damped
    assert len(found.terms) == 1, found.terms
    t = found.terms[0]
    hit = [x for x in [t, *t["indistinguishable"]]
           if (x["equation"], x["term"]) == ("roll", "phidot")]  # fmt: skip
    assert hit, t
    assert abs(hit[0]["coefficient"] + 3.0) < 0.35 * 3.0
    lo, hi = hit[0]["interval"]
    assert lo < -3.0 < hi
    assert t["p_adjusted"] <= 0.05 and t["equation"] == "roll"
    assert found.before_after["ratio_ci"][1] < 1.0  # held-out error reduced
    assert quiet.terms == [] and quiet.before_after is None
    assert quiet.test["tests"] == 43 + 42 + 41


def test_written_effects_file_round_trips_through_effects_file(damped, tmp_path):
    """The kept term written as an effects file is read by ``--effects-file``'s loader
    (``measured fit|evaluate``): the same law, a library candidate, its value the fitted
    coefficient through the law's sign (value -c for ``roll: -c * phidot``), and removed
    again afterwards."""
    from bikeid.experiments.cli.measured import use_effects_file
    from bikeid.ident.effects.library import LIBRARY

    found, _ = damped
    path = found.effects_file(tmp_path / "terms.yaml")
    names = use_effects_file(argparse.Namespace(effects_file=str(path)))
    try:
        t = found.kept[0]
        assert names == (t.entry,)
        e = EFFECTS[t.entry]
        assert e.law.key == t.law.key and t.entry in LIBRARY and e.in_library
        assert read_effects_file(path).values == {
            t.entry: pytest.approx(t.value(found.terms[0]["coefficient"]), rel=1e-12)
        }
    finally:
        unregister_effects(names)
    assert t.entry not in EFFECTS or not EFFECTS[t.entry].in_library


def test_discover_cli_refuses_an_effects_file_name_before_any_work(tmp_path, capsys):
    """``--out terms.txt`` is one line naming the fix (exit 3), before the logs are read."""
    from bikeid.experiments.cli import main
    from bikeid.sim.errors import EXIT_INPUT

    rc = main(["measured", "discover", "--data", str(tmp_path), "--out",
               str(tmp_path / "terms.txt")])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == EXIT_INPUT, err
    assert len(err.strip().splitlines()) == 1 and ".yaml, .yml or .json" in err
    assert not (tmp_path / "terms.txt").exists()


@pytest.mark.slow  # 3 discoveries on 20 decays: ~15 s of CPU
def test_a_nominal_off_by_its_uncertainty_is_not_a_term():
    """Known both ways, on decays of the independent linear plant (blind generator, white
    roll-rate noise 8 mrad/s, 8192-count encoder) whose bicycle is the stated one with every
    body's inertia 5 % off (alternating signs) and the trail 2 mm long, the edges of the
    default band (as ``test_nominal_uncertainty``'s selection test), 2 speeds x 10 decays,
    seed 11 (that test's).  No term: the stated nominal taken as exact
    (``AcceptanceRule.exact()``) keeps one (measured: ``roll: deltadot/v``, p = 1.4e-5
    against 0.05 / 126); calibrated within the default uncertainty (the default rule's),
    nothing (its best p = 0.16).  With a roll damping of -5 N m s/rad injected (outside the
    library), the calibrated discovery keeps ``roll: phidot`` (or a term whose
    indistinguishable set holds it) within 35 % of -5, its 95 % interval covering -5
    (measured -4.88 [-5.35, -4.41]); taken as exact, the interval misses it (measured
    -6.07 [-6.48, -5.66]: the term absorbs the inertia mismatch)."""
    from bikeid.experiments.measured.blind_trials import (
        BlindTrial,
        band_edge_nuisance,
        generate_windows,
        with_terms,
    )
    from bikeid.ident.effects.acceptance import AcceptanceRule

    exact = AcceptanceRule.exact()  # the stated bicycle taken as exact
    nz = band_edge_nuisance()
    trial = BlindTrial(0, 11, "none", float("nan"), (2.0, 3.5), (2.7, 4.2), nz)

    def windows(tr):
        return generate_windows(tr, tr.fit_speeds, 10, tr.seed, "fit")

    quiet = windows(trial)
    assert discover(ExperimentModel(), quiet, rule=exact).terms, "the stated nominal leaves one"
    calibrated = discover(ExperimentModel(), quiet)  # the default: the default uncertainty
    assert calibrated.terms == []
    assert set(calibrated.test["nominal_calibration"]["fit_half"]["offsets"]) == {
        "inertia_R", "inertia_B", "inertia_H", "inertia_F", "trail"}  # fmt: skip

    damped = windows(with_terms(trial, {"roll: phidot": -5.0}))

    def roll_damping(d):
        assert len(d.terms) == 1, d.terms
        t = d.terms[0]
        hit = [x for x in [t, *t["indistinguishable"]]
               if (x["equation"], x["term"]) == ("roll", "phidot")]  # fmt: skip
        assert hit, t
        return hit[0]

    got = roll_damping(discover(ExperimentModel(), damped))
    assert abs(got["coefficient"] + 5.0) < 0.35 * 5.0
    lo, hi = got["interval"]
    assert lo < -5.0 < hi
    lo, hi = roll_damping(discover(ExperimentModel(), damped, rule=exact))["interval"]
    assert not lo < -5.0 < hi
