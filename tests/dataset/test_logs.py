"""The one loader (dataset.logs) and the sign check against a nominal bicycle (dataset.signs).

Where a check refuses, the remedy its message prints is followed and must pass.  The real
logs are the TU Delft steer-by-wire logs ($BIKEID_DATA), rewritten at test time into a
stranger's CSV (ms, degrees, km/h, roll positive to the left); nothing tuned the sign check
on them (its only constant is the level 0.01 of a two-sided test).
"""

from __future__ import annotations

import csv
import dataclasses
import math
import os
from pathlib import Path

import numpy as np
import pytest

from bikeid.dataset.logs import LogOptions, load_runs, pool_runs
from bikeid.dataset.run import Run
from bikeid.dataset.signs import check_signs, sign_evidence
from bikeid.experiments.cli import main
from bikeid.sim.errors import InputError
from bikeid.sim.parameters import steer_by_wire

DATA = os.environ.get("BIKEID_DATA", str(Path(__file__).resolve().parents[3] / "shared" / "data"))
SBW = Path(DATA) / "tudelft-sbw"
needs_data = pytest.mark.skipif(not SBW.is_dir(), reason=f"no measured data at {DATA}")
#: The stranger's columns, units and sign: roll and roll rate logged positive to the left.
COLUMNS = {"phi": "roll_deg", "phidot": "roll_rate_dps", "delta": "steer_deg",
           "deltadot": "steer_rate_dps", "v": "speed_kmh", "T_delta": "torque_Nm"}  # fmt: skip
UNITS = {"t": "ms", "phi": "deg", "phidot": "deg/s", "delta": "deg", "deltadot": "deg/s",
         "v": "km/h"}  # fmt: skip
ARGS = ["--format", "csv", "--time", "time_ms",
        "--columns", ",".join(f"{k}={c}" for k, c in COLUMNS.items()),
        "--units", ",".join(f"{k}={u}" for k, u in UNITS.items())]  # fmt: skip


def _stranger_csv(run: Run, path: Path, mirror_roll: bool) -> Path:
    """A run rewritten as a stranger logs it: ms, degrees, km/h, roll positive to the left."""
    s = run.signals
    sign = -1.0 if mirror_roll else 1.0
    cols = {"time_ms": (run.t - run.t[0]) * 1000.0,
            "roll_deg": sign * np.degrees(s["phi"]),
            "roll_rate_dps": sign * np.degrees(s["phidot"]),
            "steer_deg": np.degrees(s["delta"]), "steer_rate_dps": np.degrees(s["deltadot"]),
            "speed_kmh": s["v"] * 3.6, "torque_Nm": s["T_delta"]}  # fmt: skip
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        w.writerows(np.column_stack(list(cols.values())).tolist())
    return path


@pytest.fixture(scope="module")
def real_logs(tmp_path_factory):
    """Two steer-by-wire logs (a push log at 2.5 m/s and a handlebar-sine log at 4 m/s) as a
    stranger's CSV, mirrored (roll positive to the left) and as bikeid signs."""
    if not SBW.is_dir():
        pytest.skip("no measured data")
    from bikeid.dataset.sbw_logs import load_log, settled

    d = tmp_path_factory.mktemp("stranger")
    out = {}
    for name in ("eigen/eigen_normal_sil6.5n2_9kph.log.gz",
                 "bode-4mps/bode_normal_4mps_1.5Hz.log.gz"):
        run = settled(load_log(SBW / name))
        stem = Path(name).name.split(".log")[0]
        out[stem] = (_stranger_csv(run, d / f"{stem}-left.csv", True),
                     _stranger_csv(run, d / f"{stem}-right.csv", False))
    return out


@needs_data
def test_a_mirrored_roll_axis_is_refused_and_both_fixes_pass(real_logs):
    """Roll logged positive to the left: refused naming both equivalent fixes; either fix
    (roll flipped, or steer and torque flipped) passes, and the correctly signed log passes.
    The sign coefficients are +0.5..+0.9 with |t| > 20 on these logs (dataset.signs), so the
    verdict is not near the 2.58 threshold either way."""
    p = steer_by_wire()
    for i, (left, right) in enumerate(real_logs.values()):
        opts = LogOptions(format="csv", columns=COLUMNS, units=UNITS, time="time_ms",
                          bicycle="steer-by-wire")  # fmt: skip
        with pytest.raises(InputError) as err:
            load_runs([left], opts, note=lambda _m: None)
        msg = str(err.value)
        assert "--flip phi,phidot" in msg and "--flip delta,deltadot,T_delta" in msg, msg
        runs = load_runs([right], opts, note=lambda _m: None)
        assert [c.verdict for c in sign_evidence(runs, p)] == ["confirmed", "confirmed"]
        if i:  # the remedies, followed on the first log
            continue
        for fix in (("phi", "phidot"), ("delta", "deltadot", "T_delta")):
            runs = load_runs([left], opts.replace(flip=fix), note=lambda _m: None)
            roll = sign_evidence(runs, p)[0]
            assert roll.verdict == "confirmed" and roll.t > 10, (fix, roll)
        # the last remedy: skipping the check by name passes, with a note
        notes = []
        load_runs([left], opts.replace(skip=("signs",)), note=notes.append)
        assert any("check signs skipped" in n for n in notes), notes


@needs_data
def test_the_command_line_refuses_a_mirrored_roll_axis_with_exit_3(real_logs, capsys):
    left, right = real_logs["eigen_normal_sil6.5n2_9kph"]
    argv = ["identify", str(left), *ARGS, "--bicycle", "steer-by-wire", "--quiet"]
    assert main(argv) == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "roll axis is probably logged positive to the left" in err
    assert "--flip phi,phidot" in err and "--flip delta,deltadot,T_delta" in err
    # measured fit reads the same way: refused before any decay is fitted
    out = Path(left).with_name("fit.json")
    assert main(["measured", "fit", str(left), *ARGS, "--bicycle", "steer-by-wire", "--out",
                 str(out), "--quiet"]) == 3  # fmt: skip
    err = capsys.readouterr().err
    assert "--flip phi,phidot" in err and not out.exists(), err
    # without a bicycle, identify says that the signs are unchecked (and fits)
    assert main(["identify", str(right), *ARGS, "--quiet", "--method", "pem"]) == 0
    assert "signs of roll, steer and torque are unchecked" in capsys.readouterr().err


def test_a_flipped_torque_is_refused_through_the_steer_equation():
    """The steer torque alone flipped on a simulated closed loop (dither excites the steer
    equation): the steer sign coefficient is negative beyond 2.58 SE; unflipped it is
    positive beyond 10 SE (below 1 in size: the differentiated sensor noise in Q attenuates a
    least-squares slope, errors in variables, which changes its size, not its sign)."""
    from bikeid.controllers import make
    from bikeid.controllers.excitation import UniformDither
    from bikeid.dataset.closed_loop import simulate_run
    from bikeid.sim.parameters import benchmark

    p = benchmark()
    run = simulate_run(p, make("pid", p, sample_time=0.01), 5.0, 20.0,
                       dither=UniformDither(1.0, seed=3), plant="linear")  # fmt: skip
    steer = sign_evidence([run], p)[1]
    assert steer.verdict == "confirmed" and 0 < steer.coefficient <= 1.05 and steer.t > 10, steer
    flipped = dataclasses.replace(run, signals={**run.signals,
                                                "T_delta": -run.signals["T_delta"]})
    with pytest.raises(InputError, match=r"--flip T_delta"):
        check_signs([flipped], p)


def test_no_excitation_cannot_decide_and_says_so():
    """Sensor noise only (the bicycle held upright): neither sign is decided; a note says so
    instead of a verdict."""
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 20.0, 0.01)
    sig = {k: 1e-4 * rng.standard_normal(t.size) for k in ("phi", "delta", "phidot",
                                                           "deltadot", "T_delta")}  # fmt: skip
    sig["v"] = np.full(t.size, 4.0)
    run = Run.from_arrays(t, sig, skip=["rate-derivative"])
    notes = check_signs([run], steer_by_wire(), "noise")
    assert len(notes) == 2 and all("cannot be decided" in n for n in notes), notes


def test_time_left_in_ms_is_refused_in_python_and_the_remedy_passes():
    """Run.from_arrays with the time unit left out (ms read as s: dt = 10 s) is refused by
    the loader's sample-period check, as the command line refuses it; the printed remedy
    units={'t': 'ms'} gives the true 0.01 s."""
    t = np.arange(0, 3000) * 10.0  # ms
    w = 2.0 * np.pi * 0.5
    sig = {"phi": 0.05 * np.sin(w * t / 1000), "phidot": 0.05 * w * np.cos(w * t / 1000),
           "delta": 0.02 * np.cos(w * t / 1000), "deltadot": -0.02 * w * np.sin(w * t / 1000),
           "T_delta": 0.3 * np.sin(3 * t / 1000), "v": np.full(t.size, 5.0)}  # fmt: skip
    with pytest.raises(InputError, match=r"units=\{'t': 'ms'\}") as err:
        Run.from_arrays(t, sig)
    assert "sample period 10 s" in str(err.value)
    run = Run.from_arrays(t, sig, units={"t": "ms"})
    assert run.dt == pytest.approx(0.01, rel=1e-12)
    # the other remedy, skipping by name, is recorded in the run
    run = Run.from_arrays(t, sig, skip=["sample-period", "rate-derivative"])
    assert {"sample-period", "rate-derivative"} <= set(run.meta["import"]["skipped_checks"])


def test_degrees_given_as_radians_are_refused_in_python_with_the_factor():
    t = np.arange(0, 2000) * 0.01
    sig = {"phi": np.degrees(0.05 * np.sin(3 * t)), "phidot": 0.15 * np.cos(3 * t),
           "delta": 0.01 * np.sin(2 * t), "deltadot": 0.02 * np.cos(2 * t),
           "T_delta": 0.2 * np.sin(5 * t), "v": np.full(t.size, 5.0)}  # fmt: skip
    with pytest.raises(InputError) as err:
        Run.from_arrays(t, sig, skip=["angle-bounds"])
    factor = float(str(err.value).split(" is ")[1].split(" x ")[0])
    assert factor == pytest.approx(math.pi / 180, rel=0.05)  # the true factor, 1/57.3
    assert "units={'phi': 'deg'}" in str(err.value)
    run = Run.from_arrays(t, sig, units={"phi": "deg"})
    assert np.max(np.abs(run.signals["phi"])) == pytest.approx(0.05, rel=1e-3)


def _plain_csv(path: Path, v: np.ndarray) -> Path:
    t = np.arange(v.size) * 0.01
    w = 2 * np.pi * 0.8
    cols = {"t": t, "phi": 0.03 * np.sin(w * t), "phidot": 0.03 * w * np.cos(w * t),
            "delta": 0.01 * np.sin(w * t + 1), "deltadot": 0.01 * w * np.cos(w * t + 1),
            "T": 0.2 * np.sin(7 * t), "v": v}  # fmt: skip
    with path.open("w", newline="") as f:
        wr = csv.writer(f)
        wr.writerow(cols)
        wr.writerows(np.column_stack(list(cols.values())).tolist())
    return path


def test_a_csv_without_format_is_read_as_csv_with_columns_else_refused(tmp_path, capsys):
    """A .csv given without --format: with --columns read as CSV (a note says so); without,
    the refusal names CSV and --columns instead of 'not a readable HDF5 file'."""
    f = _plain_csv(tmp_path / "ride.csv", np.full(3000, 4.0))
    assert main(["identify", str(f), "--quiet", "--method", "direct"]) == 3
    err = capsys.readouterr().err
    assert "is CSV text" in err and "--format csv --columns" in err and "HDF5" not in err, err
    cols = "phi=phi,phidot=phidot,delta=delta,deltadot=deltadot,T_delta=T,v=v"
    runs = load_runs([f], LogOptions(columns=dict(p.split("=") for p in cols.split(","))),
                     note=lambda _m: None)  # fmt: skip
    assert len(runs) == 1 and runs[0].dt == pytest.approx(0.01)


def test_a_stretch_whose_speed_trends_is_dropped_with_a_note(tmp_path):
    """A treadmill speeding up 0.55 -> 0.85 m/s over 30 s, then steady for 20 s: the split
    keeps stretches within the 0.25 m/s tolerance, but the first changes speed by about
    0.25 m/s along it, a third of its speed: not one constant-speed model (the limit is the
    smaller of the tolerance and the importer's 10 % of the speed).  It is dropped with a
    note; the stretch at the steady 0.85 m/s is kept.  A pure ramp is refused, and the
    remedy (cut the steady part with --start/--stop) passes."""
    cols = {"phi": "phi", "phidot": "phidot", "delta": "delta", "deltadot": "deltadot",
            "T_delta": "T", "v": "v"}  # fmt: skip
    opts = LogOptions(format="csv", columns=cols)
    log = _plain_csv(tmp_path / "log.csv", np.r_[np.linspace(0.55, 0.85, 3000),
                                                 np.full(2000, 0.85)])  # fmt: skip
    notes: list[str] = []
    runs = load_runs([log], opts, notes.append)
    assert len(runs) == 1 and runs[0].speed == pytest.approx(0.85, abs=0.01)
    dropped = [n for n in notes if "dropped" in n]
    assert len(dropped) == 1 and "changes 0.2" in dropped[0], notes
    ramp = _plain_csv(tmp_path / "ramp.csv", np.linspace(0.55, 0.85, 3000))
    with pytest.raises(InputError, match="--start/--stop"):
        load_runs([ramp], opts, notes.append)
    runs = load_runs([log], opts.replace(start=30.0), notes.append)
    assert len(runs) == 1 and runs[0].speed == pytest.approx(0.85)


def test_pooled_speed_is_the_sample_weighted_mean_of_the_sensor_speeds():
    """The model speed of pooled runs is their sample-weighted mean measured speed; each
    run keeps its own as measured_speed (what the import docs state)."""
    t = np.arange(0, 1000) * 0.01
    sig = {"phi": 0.01 * np.sin(t), "phidot": 0.01 * np.cos(t), "delta": 0.01 * np.cos(t),
           "deltadot": -0.01 * np.sin(t), "T_delta": 0.1 * np.sin(4 * t)}  # fmt: skip
    a = Run.from_arrays(t, {**sig, "v": np.full(t.size, 4.0)})
    b = Run.from_arrays(t[:500], {k: x[:500] for k, x in {**sig, "v": np.full(t.size, 4.2)
                                                          }.items()})  # fmt: skip
    pooled = pool_runs([a, b], 0.25)
    mean = (4.0 * 1000 + 4.2 * 500) / 1500
    assert [r.speed for r in pooled] == pytest.approx([mean, mean], rel=1e-6)
    assert [r.meta["measured_speed"] for r in pooled] == pytest.approx([4.0, 4.2])


def test_decays_from_logs_counts_every_push_of_the_generator(tmp_path):
    """ident.effects.decays_from_logs on the closure generator's CSV logs (its own import
    options, roll logged positive to the left): every one of the generator's 8 pushes per
    log is counted (kept or rejected), as the command line reads them."""
    from bikeid.experiments.measured.blind_trials import (
        CLOSURE_EFFECTS,
        LOG_PUSHES,
        draw_blind_trials,
        log_options,
        write_trial_logs,
    )
    from bikeid.ident.effects import decays_from_logs

    trial = draw_blind_trials(len(CLOSURE_EFFECTS), 0, CLOSURE_EFFECTS)[0]
    files = write_trial_logs(trial, tmp_path, "independent_linear")
    windows, model, law, report = decays_from_logs(files, log_options(), note=lambda _m: None)
    counted = sum(f["kept"] + len(f["rejected"]) for f in report["files"])
    assert counted == LOG_PUSHES * len(files)
    assert len(windows) == sum(f["kept"] for f in report["files"]) and law is None
    assert model.p.name == steer_by_wire().name
    # the same logs without the generator's --flip phi,phidot: a mirrored roll axis
    with pytest.raises(InputError, match="--flip phi,phidot"):
        decays_from_logs(files, log_options().replace(flip=()), note=lambda _m: None)
