"""The import's range checks through the command line: refused by default with the cause,
skipped by name (``--skip-check torque-bounds``, ``--no-checks``) with a note printed and
stored, in every command that reads a user's logs (identify, validate, measured fit); a
speed with a unit of the one table, any case that cannot mislead (``--speed 18KM/H``).

Data: the exact linear closed loop of the benchmark bicycle at 5 m/s with 1 N m dither
(``dataset.linear_loop.simulate``), written as an ordinary logger's CSV (ms, degrees,
km/h, roll positive to the left) with one steer-torque sample of 250 N m: beyond the
200 N m bound of ``sim.conventions.PLAUSIBLE`` (a knock on the handlebar a user may know of).
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from bikeid.experiments.cli import main

COLS = ("phi=Roll_deg,phidot=RollRate_dps,delta=Steer_deg,deltadot=SteerRate_dps,"
        "v=Speed_kmh,T_delta=SteerTorque_Nm")  # fmt: skip
UNITS = "phi=deg,phidot=deg/s,delta=deg,deltadot=deg/s,v=km/h,t=ms"
READ = ["--format", "csv", "--columns", COLS, "--units", UNITS, "--time", "Time_ms",
        "--flip", "phi,phidot"]  # fmt: skip


def _cli(argv, cwd: Path) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.chdir(cwd), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(list(map(str, argv)))
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Path:
    from bikeid.dataset.linear_loop import simulate
    from bikeid.dataset.store import write_runs
    from bikeid.sim.parameters import benchmark

    d = tmp_path_factory.mktemp("checks")
    run = simulate(benchmark(), 5.0, duration=20.0, seed=3, dither=1.0, rate_noise=1e-3,
                   angle_noise=1e-4)  # fmt: skip
    write_runs(d / "runs.h5", [run], names=["v5"])
    tq = run["T_delta"].copy()
    tq[700] = 250.0  # the knock
    table = np.column_stack([1000 * run.t, -np.degrees(run["phi"]), -np.degrees(run["phidot"]),
                             np.degrees(run["delta"]), np.degrees(run["deltadot"]),
                             3.6 * run["v"], tq])  # fmt: skip
    for name, t in (("ride.csv", table), ("ride_nospeed.csv", np.delete(table, 5, axis=1))):
        head = "Time_ms,Roll_deg,RollRate_dps,Steer_deg,SteerRate_dps,Speed_kmh,SteerTorque_Nm"
        if "nospeed" in name:
            head = head.replace("Speed_kmh,", "")
        with (d / name).open("w") as fh:
            fh.write(head + "\n")
            np.savetxt(fh, t, delimiter=",", fmt="%.17g")
    return d


def test_a_range_check_refuses_by_default_naming_unit_corruption_and_option(logs):
    rc, _, err = _cli(["identify", "ride.csv", *READ], logs)
    assert rc == 3, err
    last = err.strip().splitlines()[-1]
    assert "Traceback" not in err and "ride.csv: row 702, column 'SteerTorque_Nm'" in last
    assert "value 250 N m" in last and "physical range -200..200 N m of T_delta" in last
    i, j = last.index("in N cm?"), last.index("corrupt")
    assert i < j < last.index("--skip-check torque-bounds"), last


def test_skipping_it_by_name_is_noted_printed_and_stored(logs):
    rc, out, err = _cli(["identify", "ride.csv", *READ, "--skip-check", "torque-bounds",
                         "--json", "--out", "m.json"], logs)  # fmt: skip
    assert rc == 0, err
    note = "check torque-bounds skipped on request: values beyond the physical range"
    assert f"note: {note}" in err
    assert any(n.startswith(note) for n in json.loads(out)["notes"])
    from bikeid.ident.model_file import read_model_file

    assert read_model_file(logs / "m.json").settings["skipped_checks"] == ["torque-bounds"]
    # validate reads the same log: refused without the skip, noted with it
    rc, _, err = _cli(["validate", "ride.csv", "--model", "m.json"], logs)
    assert rc == 3 and "--skip-check torque-bounds" in err, err
    rc, _, err = _cli(["validate", "ride.csv", "--model", "m.json", "--skip-check",
                       "torque-bounds"], logs)  # fmt: skip
    assert rc == 0 and f"note: {note}" in err, err


def test_no_checks_notes_every_range_check(logs):
    rc, _, err = _cli(["identify", "ride.csv", *READ, "--no-checks", "--quiet"], logs)
    assert rc == 0, err
    for name in ("angle", "rate", "speed", "torque", "force"):
        assert f"note: check {name}-bounds skipped on request" in err, name


def test_measured_fit_shares_the_reader(logs):
    """measured fit reads logs with identify's reader: the same refusal, the same skip (it
    then stops at the next missing option, --bicycle: the import passed)."""
    rc, _, err = _cli(["measured", "fit", "ride.csv", *READ, "--out", "fit.json"], logs)
    assert rc == 3 and "--skip-check torque-bounds" in err, err
    rc, _, err = _cli(["measured", "fit", "ride.csv", *READ, "--out", "fit.json",
                       "--skip-check", "torque-bounds"], logs)  # fmt: skip
    assert rc == 3 and "need --bicycle" in err and "check torque-bounds skipped" in err, err


def test_range_checks_of_bikeid_files_cannot_be_skipped(logs):
    """Run files written by bikeid and the steer-by-wire logs are always range-checked: a
    skip by name is refused, --no-checks says so (never a skip that silently does nothing)."""
    rc, _, err = _cli(["identify", "runs.h5", "--skip-check", "angle-bounds"], logs)
    assert rc == 3 and "applies to --format csv or hdf5" in err, err
    rc, _, err = _cli(["identify", "runs.h5", "--no-checks", "--quiet", "--out", "m.json"],
                      logs)  # fmt: skip
    assert rc == 0 and "range checks (angle-bounds, rate-bounds" in err, err
    assert "still run on --format bikeid files" in err
    # the model file records the checks that were skipped, not the range checks that ran
    settings = json.loads((logs / "m.json").read_text())["settings"]
    assert settings["skipped_checks"] == ["sample-period", "rate-derivative", "signs",
                                          "informativity"]
    rc, _, err = _cli(["measured", "fit", "--format", "sbw", "--data", "nowhere", "--out",
                       "f.json", "--skip-check", "rate-bounds"], logs)  # fmt: skip
    assert rc == 3 and "applies to --format csv or hdf5" in err, err


def test_a_speed_in_any_unambiguous_case_gives_the_same_model(logs):
    """18 km/h is exactly 5 m/s: the constant nominal speed of a log without a speed column
    gives the same eigenvalues (to the printed digits) whichever way it is written."""
    read = [*READ[:3], COLS.replace(",v=Speed_kmh", ""), "--units",
            UNITS.replace(",v=km/h", ""), *READ[6:], "--skip-check", "torque-bounds", "--json",
            "--quiet"]  # fmt: skip
    got = []
    for speed in ("5", "18km/h", "18 KM/H", "5M/S"):
        rc, out, err = _cli(["identify", "ride_nospeed.csv", *read, "--speed", speed], logs)
        assert rc == 0, (speed, err)
        got.append(json.loads(out)["per_speed"][0]["eigenvalues"])
    assert all(g == got[0] for g in got[1:])
    rc, _, err = _cli(["identify", "ride_nospeed.csv", *read, "--speed", "5Ms"], logs)
    assert rc == 2 and "--speed" in err and "unit of a time" in err, err


def test_the_toppling_rate_check_of_decays_refuses_then_skips_with_rate_bounds():
    """measured fit's bicycle-specific roll-rate bound (the toppling rate, 5.24 rad/s for the
    steer-by-wire bicycle) is a rate range check too: refused by default naming the unit
    first and the skip, not run with rate-bounds skipped (the reader notes the skip)."""
    import dataclasses

    from bikeid.ident.effects.experiment_model import ExperimentModel
    from bikeid.ident.effects.log_decays import check_decay_rates
    from bikeid.ident.effects.synthetic_decays import synthetic_windows
    from bikeid.sim.errors import InputError
    from bikeid.sim.parameters import steer_by_wire

    ws = synthetic_windows(ExperimentModel(), [2.5], per_speed=1, seed=1)
    bad = ws[0].phidot.copy()
    bad[40] = 15.0  # inside the generic 20 rad/s, 2.9 x the toppling rate
    ws = [dataclasses.replace(ws[0], phidot=bad)]
    with pytest.raises(InputError) as e:
        check_decay_rates(ws, steer_by_wire())
    msg = str(e.value)
    assert msg.index("--units") < msg.index("glitch") < msg.index("--skip-check rate-bounds")
    check_decay_rates(ws, steer_by_wire(), ["rate-bounds"])  # skipped: nothing raised
    with pytest.raises(InputError):
        check_decay_rates(ws, steer_by_wire(), ["angle-bounds"])  # another skip: still runs
