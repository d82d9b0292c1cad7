"""The one data object, a Run: from numpy arrays with the user's names, from a pandas DataFrame
and from python-control's TimeResponseData (``Run.from_arrays``, ``Run.from_dataframe``,
``Run.from_timeresponse``; ``dataset.importers`` names the same functions), to
TimeResponseData (``Run.to_timeresponse``), with units and sample time checked; each range
check refused by default with the unit first, accepted when skipped by name and recorded.

Independent sources: the SI conversions computed here with numpy (``np.radians``, / 3.6,
/ 1000) rather than the importers' table; python-control's own simulation of the benchmark
bicycle (``control.forced_response`` of the ZOH-sampled ``sim.linear`` model) for a response
that PEM must then identify to round-off.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.dataset import importers
from bikeid.dataset.run import BOUND_CHECKS, Run, bound_check
from bikeid.sim.conventions import PLAUSIBLE, UNITS

DT = 0.01
N = 600
T = np.arange(N) * DT
RNG = np.random.default_rng(3)
# a plausible ride: small angles and rates, a torque, 18 km/h
SI = {
    "phi": 0.02 * np.sin(1.3 * T), "delta": 0.03 * np.sin(2.1 * T + 0.4),
    "phidot": 0.026 * np.cos(1.3 * T), "deltadot": 0.063 * np.cos(2.1 * T + 0.4),
    "T_delta": 0.5 * np.sin(3.0 * T) + 0.05 * RNG.standard_normal(N), "v": np.full(N, 5.0),
}  # fmt: skip
MAPPING = {"phi": "roll", "delta": "steer", "phidot": "roll_rate", "deltadot": "steer_rate",
           "T_delta": "torque", "v": "speed"}  # fmt: skip
UNITS_USER = {"t": "ms", "phi": "deg", "delta": "deg", "phidot": "deg/s", "deltadot": "deg/s",
              "v": "km/h"}  # fmt: skip


def _users_arrays(flip_roll: bool = True) -> dict[str, np.ndarray]:
    """The ride as a logger writes it: degrees, km/h, roll positive to the left."""
    s = -1.0 if flip_roll else 1.0
    return {"roll": s * np.degrees(SI["phi"]), "steer": np.degrees(SI["delta"]),
            "roll_rate": s * np.degrees(SI["phidot"]), "steer_rate": np.degrees(SI["deltadot"]),
            "torque": SI["T_delta"], "speed": SI["v"] * 3.6}  # fmt: skip


def _check_si(run: Run) -> None:
    """Signals equal the SI ride to rounding of one multiply and its inverse (1e-12 rel)."""
    for k, x in SI.items():
        np.testing.assert_allclose(run[k], x, rtol=1e-12, atol=1e-15, err_msg=k)


def test_from_arrays_with_own_names_units_and_signs():
    run = Run.from_arrays(T * 1000.0, _users_arrays(), MAPPING, UNITS_USER,
                          flip=["phi", "phidot"])  # fmt: skip
    _check_si(run)
    assert run.dt == pytest.approx(DT, rel=1e-9) and run.speed == pytest.approx(5.0)
    imp = run.meta["import"]
    assert imp["dt"] == pytest.approx(DT, rel=1e-9)
    assert imp["units"]["phi"] == {"from": "deg", "to": "rad", "factor": pytest.approx(np.pi / 180)}
    assert imp["units"]["t"]["from"] == "ms" and imp["flip"] == ["phi", "phidot"]


def test_from_arrays_defaults_to_bikeid_names_and_si():
    run = Run.from_arrays(T, SI)
    _check_si(run)
    assert run.meta["import"]["columns"] == {k: k for k in SI}


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"dt": 0.02}, "dt=0.02 s given but the file is sampled every"),
        ({"units": {"phi": "grad"}}, "unit 'grad' for 'phi' is not supported"),
        ({"mapping": {**MAPPING, "phi": "pitch"}}, "pitch"),
        ({"mapping": {k: v for k, v in MAPPING.items() if k != "T_delta"}}, "T_delta"),
    ],
)
def test_from_arrays_refuses_with_the_cause(kwargs, words):
    args = {"mapping": MAPPING, "units": UNITS_USER, **kwargs}
    with pytest.raises(ValueError, match=words.replace("(", r"\(")):
        Run.from_arrays(T * 1000.0, _users_arrays(False), args["mapping"], args["units"],
                        dt=kwargs.get("dt"))  # fmt: skip


def test_from_arrays_refuses_irregular_sampling_and_ragged_arrays():
    t = T.copy()
    t[300:] += 0.5 * DT  # a gap of half a sample
    with pytest.raises(ValueError, match="irregular sampling"):
        Run.from_arrays(t, SI)
    with pytest.raises(ValueError, match="different lengths"):
        Run.from_arrays(T, {**SI, "phi": SI["phi"][:-1]})


def test_from_dataframe_reads_a_pandas_frame():
    pd = pytest.importorskip("pandas")  # in the test extra: runs in CI
    df = pd.DataFrame({"time_ms": T * 1000.0, **_users_arrays()})
    run = Run.from_dataframe(df, MAPPING, UNITS_USER, time="time_ms", flip=["phi", "phidot"])
    _check_si(run)
    assert run.dt == pytest.approx(DT, rel=1e-9)
    with pytest.raises(ValueError, match="time_s"):
        Run.from_dataframe(df, MAPPING, UNITS_USER, time="time_s")


def test_timeresponse_round_trip_keeps_names_units_and_sample_time():
    run = Run.from_arrays(T, SI)
    resp = run.to_timeresponse(outputs=("phi", "delta", "phidot", "deltadot", "v"))
    assert list(resp.output_labels) == ["phi", "delta", "phidot", "deltadot", "v"]
    assert list(resp.input_labels) == ["T_delta"]
    assert resp.params["units"] == {k: UNITS[k] for k in [*SI]}
    assert resp.params["dt"] == run.dt and resp.params["speed"] == run.speed
    back = Run.from_timeresponse(resp)
    for k in SI:
        np.testing.assert_array_equal(back[k], run[k])
    np.testing.assert_array_equal(back.t, run.t)


def test_a_python_control_simulation_is_identified_to_round_off():
    """python-control simulates the ZOH-sampled benchmark at 5 m/s (stable there: between
    v_w = 4.29 and v_c = 6.02 m/s) under a random torque; the response, as a Run, gives PEM
    the true eigenvalues (noise-free data of the model's own structure: round-off of a
    converged fit, observed below 1e-12 relative; tolerance 1e-8)."""
    import control

    from bikeid.ident.methods import METHODS
    from bikeid.sim.linear import eigenvalues, state_space
    from bikeid.sim.parameters import benchmark

    p = benchmark()
    sysd = control.c2d(state_space(p, 5.0, inputs=("T_delta",)), DT, method="zoh")
    u = np.repeat(np.random.default_rng(0).uniform(-1, 1, 300), 4)[: 1000]
    t = np.arange(u.size) * DT
    resp = control.forced_response(sysd, T=t, U=u)
    run = Run.from_timeresponse(resp, speed=5.0)
    assert run.dt == pytest.approx(DT) and run.speed == 5.0
    np.testing.assert_array_equal(run["delta"], np.asarray(resp.outputs)[1])
    res = METHODS["pem"].fit(run)
    truth = np.sort_complex(eigenvalues(p, 5.0))
    err = np.abs(np.asarray(res.eigenvalues(5.0)) - truth) / np.abs(truth)
    assert err.max() < 1e-8, err


def test_timeresponse_of_several_traces_is_refused():
    import control

    from bikeid.sim.linear import state_space
    from bikeid.sim.parameters import benchmark

    sysd = control.c2d(state_space(benchmark(), 5.0, inputs=("T_delta",)), DT, method="zoh")
    resp = control.forced_response(sysd, T=T, U=SI["T_delta"])
    resp2 = control.TimeResponseData(resp.time, np.stack([resp.outputs, resp.outputs], axis=1),
                                     output_labels=resp.output_labels, issiso=False,
                                     multi_trace=True)  # fmt: skip
    with pytest.raises(ValueError, match="single-trace"):
        Run.from_timeresponse(resp2, speed=5.0)


@settings(max_examples=20, deadline=None)
@given(unit=st.sampled_from(["deg", "rad"]), flip=st.booleans(), ms=st.booleans())
def test_any_declared_unit_and_sign_gives_the_same_si_run(unit, flip, ms):
    """Property: however the arrays are scaled and signed, declaring it gives one SI run."""
    scale = np.degrees(1.0) if unit == "deg" else 1.0
    sign = -1.0 if flip else 1.0
    arrays = {"phi": sign * scale * SI["phi"], "phidot": sign * scale * SI["phidot"],
              "delta": SI["delta"], "deltadot": SI["deltadot"], "T_delta": SI["T_delta"],
              "v": SI["v"]}  # fmt: skip
    units = {"phi": unit, "phidot": f"{unit}/s", **({"t": "ms"} if ms else {})}
    run = Run.from_arrays(T * (1000.0 if ms else 1.0), arrays, None, units,
                          flip=["phi", "phidot"] if flip else [])  # fmt: skip
    _check_si(run)


def test_the_constructors_are_classmethods_and_the_importers_names_alias_them():
    """One implementation: the importers' functions are the Run classmethods themselves."""
    for name in ("from_arrays", "from_dataframe", "from_timeresponse"):
        assert getattr(importers, name).__func__ is getattr(Run, name).__func__, name
    assert isinstance(Run.from_arrays(T, SI), Run)


def test_every_bounded_signal_has_a_named_range_check():
    """Each name of sim.conventions.PLAUSIBLE falls under the check of its unit."""
    assert {k: bound_check(k) for k in PLAUSIBLE} == {
        "phi": "angle-bounds", "delta": "angle-bounds", "theta": "angle-bounds",
        "phidot": "rate-bounds", "deltadot": "rate-bounds", "psidot": "rate-bounds",
        "thetaRdot": "rate-bounds", "v": "speed-bounds", "T_delta": "torque-bounds",
        "T_phi": "torque-bounds", "F": "force-bounds"}  # fmt: skip
    assert bound_check("psi") is None and bound_check("x") is None  # unbounded: no check


# One out-of-range case per range check, each the typical unit mistake: the value a
# logger in the other unit writes, read as SI (30 deg as rad, 100 deg/s as rad/s, 40 km/h
# as m/s, 300 N cm as N m); F has no other unit in the table.
_OUT_OF_RANGE = [
    ("angle-bounds", "phi", np.degrees(SI["phi"]) + 30.0, "in deg?"),
    ("rate-bounds", "phidot", np.degrees(SI["phidot"]) + 100.0, "in deg/s?"),
    ("speed-bounds", "v", np.full(N, 40.0), "in km/h or mph?"),
    ("torque-bounds", "T_delta", 300.0 + 100 * SI["T_delta"], "in N cm?"),
    ("force-bounds", "F", 5000.0 + SI["T_delta"], "unit and sign first"),
]


@pytest.mark.parametrize(("check", "signal", "values", "hint"), _OUT_OF_RANGE)
def test_a_range_check_refuses_naming_the_unit_then_corruption_then_the_skip(
    check, signal, values, hint
):
    arrays = {**SI, signal: values}
    with pytest.raises(ValueError) as e:
        Run.from_arrays(T, arrays)
    msg = str(e.value)
    lo, hi = PLAUSIBLE[signal]
    assert f"physical range {lo:g}..{hi:g}" in msg and f"of {signal}" in msg
    # the order the refusal promises: the unit (or sign), then corruption, then the option
    i, j, k = msg.index(hint), msg.index("corrupt"), msg.index(f"--skip-check {check}")
    assert i < j < k, msg
    assert f"skip=[{check!r}]" in msg and "\n" not in msg
    # (an angle or rate in the other unit also fails the rate-derivative check, which runs
    # after the range checks: skipped too, and both recorded)
    extra = ["rate-derivative"] if signal in ("phi", "phidot") else []
    run = Run.from_arrays(T, arrays, skip=[check, *extra])
    np.testing.assert_array_equal(run[signal], values)  # kept as given
    assert run.meta["import"]["skipped_checks"] == sorted([check, *extra])
    others = [c for c in BOUND_CHECKS if c != check]
    with pytest.raises(ValueError, match=check):  # another check's skip does not cover it
        Run.from_arrays(T, arrays, skip=others)


def test_a_misspelled_skip_is_refused_not_ignored():
    # 'angle-bound' (no s) names no check: ignoring it would leave the user believing the
    # angle range is unchecked while the import still refuses for another reason
    arrays = {**SI, "phi": np.degrees(SI["phi"]) + 30.0}
    with pytest.raises(ValueError, match=r"skip=\['angle-bound'\]: no such check; choose from "
                       r"angle-bounds, rate-bounds"):
        Run.from_arrays(T, arrays, skip=["angle-bound"])
    run = Run.from_arrays(T, SI, skip=["sample-period", "informativity"])  # known: accepted
    # the sample-period check runs in Python too, so its skip is recorded; informativity is
    # the fitters' check, not the import's
    assert run.meta["import"]["skipped_checks"] == ["sample-period"]


def test_a_negative_speed_suggests_the_sign_and_a_declared_unit_is_not_suggested_again():
    from bikeid.dataset.run import check_plausible

    with pytest.raises(ValueError, match=r"sign first \(logged backwards\? --flip v"):
        check_plausible(Run(T, {**SI, "v": np.full(N, -5.0)}), "ride")
    users = _users_arrays(False)
    users["roll"] = users["roll"] * 100.0  # centidegrees declared as degrees
    with pytest.raises(ValueError, match=r"read as deg: is that its unit\?") as e:
        Run.from_arrays(T * 1000.0, users, MAPPING, UNITS_USER)
    assert "in deg?" not in str(e.value)


def test_a_nominal_speed_beyond_the_range_suggests_its_unit_and_the_skip():
    no_v = {k: x for k, x in SI.items() if k != "v"}
    with pytest.raises(ValueError, match=r"in km/h\? give --speed 40km/h.*speed-bounds"):
        Run.from_arrays(T, no_v, speed=40.0)
    run = Run.from_arrays(T, no_v, speed=40.0, skip=["speed-bounds"])
    assert run.speed == 40.0 and run.meta["import"]["skipped_checks"] == ["speed-bounds"]


def test_arrays_and_the_same_csv_give_the_same_pem_model(tmp_path):
    """A user's ride (python-control's simulation of the ZOH benchmark at 5 m/s, with sensor
    noise) as arrays with the user's names and units (ms, deg, deg/s, km/h, roll positive to
    the left) and as the CSV file a logger would write of them (17 significant digits:
    float64 exactly) give identical runs, hence the same PEM model; the tolerance 1e-10
    relative on the eigenvalues only allows for a non-deterministic BLAS."""
    import control

    from bikeid.dataset.importers import from_csv
    from bikeid.ident.methods import METHODS
    from bikeid.sim.linear import state_space
    from bikeid.sim.parameters import benchmark

    sysd = control.c2d(state_space(benchmark(), 5.0, inputs=("T_delta",)), DT, method="zoh")
    rng = np.random.default_rng(7)
    u = np.repeat(rng.uniform(-1, 1, 300), 4)[:1000]
    t = np.arange(u.size) * DT
    y = np.asarray(control.forced_response(sysd, T=t, U=u).outputs)
    y = y + 1e-4 * rng.standard_normal(y.shape)
    users = {"roll_deg": -np.degrees(y[0]), "steer_deg": np.degrees(y[1]),
             "roll_rate_dps": -np.degrees(y[2]), "steer_rate_dps": np.degrees(y[3]),
             "torque_Nm": u, "speed_kmh": np.full(u.size, 18.0)}  # fmt: skip
    mapping = {"phi": "roll_deg", "delta": "steer_deg", "phidot": "roll_rate_dps",
               "deltadot": "steer_rate_dps", "T_delta": "torque_Nm", "v": "speed_kmh"}
    units = {"t": "ms", "phi": "deg", "delta": "deg", "phidot": "deg/s", "deltadot": "deg/s",
             "v": "km/h"}  # fmt: skip
    a = Run.from_arrays(t * 1000.0, users, mapping, units, flip=["phi", "phidot"])
    path = tmp_path / "ride.csv"
    names = ["Time_ms", *users]
    table = np.column_stack([t * 1000.0, *users.values()])
    path.write_text(",".join(names) + "\n"
                    + "\n".join(",".join(repr(float(x)) for x in row) for row in table) + "\n")
    b = from_csv(path, mapping, units, time="Time_ms", flip=["phi", "phidot"])
    for k in ("phi", "delta", "phidot", "deltadot", "T_delta", "v"):
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    assert a.speed == pytest.approx(5.0, rel=1e-15)  # 18 km/h, exactly 5 m/s to rounding
    ea = np.asarray(METHODS["pem"].fit(a).eigenvalues(a.speed))
    eb = np.asarray(METHODS["pem"].fit(b).eigenvalues(b.speed))
    np.testing.assert_allclose(eb, ea, rtol=1e-10)


def test_units_of_a_mapping_are_read_case_insensitively_unless_ambiguous():
    """'DEG', 'Deg/S', 'KM/H' and 'MS'... : the first three are the table's units (recorded
    in their table spelling), a time in 'Ms' (megaseconds in SI) is refused naming 'ms'."""
    units = {"t": "ms", "phi": "DEG", "delta": "Deg", "phidot": "Deg/S", "deltadot": "DEG/S",
             "v": "KM/H"}  # fmt: skip
    run = Run.from_arrays(T * 1000.0, _users_arrays(), MAPPING, units, flip=["phi", "phidot"])
    _check_si(run)
    assert {k: c["from"] for k, c in run.meta["import"]["units"].items()} == {
        **UNITS_USER, "T_delta": "N m"}
    with pytest.raises(ValueError, match=r"'Ms' for 't' is ambiguous.*megasecond.*write 'ms'"):
        Run.from_arrays(T * 1000.0, _users_arrays(), MAPPING, {**units, "t": "Ms"})
    mph = Run.from_arrays(T, {**SI, "v": SI["v"] / 0.44704}, units={"v": "mph"})
    np.testing.assert_allclose(mph["v"], SI["v"], rtol=1e-15)  # 1 mph = 0.44704 m/s (NIST)
