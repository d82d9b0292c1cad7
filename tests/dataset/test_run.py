"""The one data object, a Run: from numpy arrays with the user's names, from a pandas DataFrame
and from python-control's TimeResponseData (``dataset.importers``), to TimeResponseData
(``Run.to_timeresponse``), with units and sample time checked.

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

from bikeid.dataset.importers import from_arrays, from_dataframe, from_timeresponse
from bikeid.dataset.run import Run
from bikeid.sim.conventions import UNITS

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
    run = from_arrays(T * 1000.0, _users_arrays(), MAPPING, UNITS_USER,
                          flip=["phi", "phidot"])  # fmt: skip
    _check_si(run)
    assert run.dt == pytest.approx(DT, rel=1e-9) and run.speed == pytest.approx(5.0)
    imp = run.meta["import"]
    assert imp["dt"] == pytest.approx(DT, rel=1e-9)
    assert imp["units"]["phi"] == {"from": "deg", "to": "rad", "factor": pytest.approx(np.pi / 180)}
    assert imp["units"]["t"]["from"] == "ms" and imp["flip"] == ["phi", "phidot"]


def test_from_arrays_defaults_to_bikeid_names_and_si():
    run = from_arrays(T, SI)
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
        from_arrays(T * 1000.0, _users_arrays(False), args["mapping"], args["units"],
                        dt=kwargs.get("dt"))  # fmt: skip


def test_from_arrays_refuses_irregular_sampling_and_ragged_arrays():
    t = T.copy()
    t[300:] += 0.5 * DT  # a gap of half a sample
    with pytest.raises(ValueError, match="irregular sampling"):
        from_arrays(t, SI)
    with pytest.raises(ValueError, match="different lengths"):
        from_arrays(T, {**SI, "phi": SI["phi"][:-1]})


def test_from_dataframe_reads_a_pandas_frame():
    pd = pytest.importorskip("pandas")  # in the test extra: runs in CI
    df = pd.DataFrame({"time_ms": T * 1000.0, **_users_arrays()})
    run = from_dataframe(df, MAPPING, UNITS_USER, time="time_ms", flip=["phi", "phidot"])
    _check_si(run)
    assert run.dt == pytest.approx(DT, rel=1e-9)
    with pytest.raises(ValueError, match="time_s"):
        from_dataframe(df, MAPPING, UNITS_USER, time="time_s")


def test_timeresponse_round_trip_keeps_names_units_and_sample_time():
    run = from_arrays(T, SI)
    resp = run.to_timeresponse(outputs=("phi", "delta", "phidot", "deltadot", "v"))
    assert list(resp.output_labels) == ["phi", "delta", "phidot", "deltadot", "v"]
    assert list(resp.input_labels) == ["T_delta"]
    assert resp.params["units"] == {k: UNITS[k] for k in [*SI]}
    assert resp.params["dt"] == run.dt and resp.params["speed"] == run.speed
    back = from_timeresponse(resp)
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
    run = from_timeresponse(resp, speed=5.0)
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
        from_timeresponse(resp2, speed=5.0)


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
    run = from_arrays(T * (1000.0 if ms else 1.0), arrays, None, units,
                          flip=["phi", "phidot"] if flip else [])  # fmt: skip
    _check_si(run)
