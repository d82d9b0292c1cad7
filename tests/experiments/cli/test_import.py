"""A user's own logs through the command line: ``bikeid export`` writes CSV with units,
``bikeid identify --format csv`` reads a log in other units and column names.

The same closed-loop data identified from bikeid's HDF5 file and from a "user's log" (the
exported CSV rewritten in degrees, deg/s, km/h and milliseconds under other names) must give
the same PEM eigenvalues: the unit conversions change each sample by at most 2 eps relative
(tests/dataset/test_importers.py), far below what moves a prediction-error optimum, so the two
agree to 1e-6 1/s (observed: identical to the printed digits); both lie within the
project's accuracy goal of the true eigenvalues (Meijaard 2007 linearization).
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
from pathlib import Path

import numpy as np
import pytest

from bikeid.experiments.cli import main


def _run(argv, cwd: Path) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.chdir(cwd), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    from bikeid.dataset.linear_loop import simulate
    from bikeid.dataset.store import write_runs
    from bikeid.sim.parameters import benchmark

    d = tmp_path_factory.mktemp("import")
    p = benchmark()
    runs = [simulate(p, v, duration=40.0, seed=i, rate_noise=1e-3, angle_noise=1e-4)
            for i, v in enumerate((4.0, 5.0))]  # fmt: skip
    write_runs(d / "runs.h5", runs, names=["v4", "v5"])
    return d


def _eigs(text: str) -> dict[float, np.ndarray]:
    res = json.loads(text)
    return {
        row["speed"]: np.array([complex(z["re"], z["im"]) for z in row["eigenvalues"]])
        for row in res["per_speed"]
    }


def test_export_then_identify_a_users_log(folder):
    rc, out, err = _run(["export", "runs.h5", "--out", "csv"], folder)
    assert rc == 0, err
    names = sorted(p.name for p in (folder / "csv").iterdir())
    assert names == [".bikeid-folder.json", ".bikeid-folder.lock", "v4.csv", "v5.csv"]
    owned = json.loads((folder / "csv" / ".bikeid-folder.json").read_text())  # its marker
    assert owned == {"command": "bikeid export", "files": ["v4.csv", "v5.csv"]}
    header = (folder / "csv" / "v4.csv").read_text().splitlines()[1]
    assert "phi [rad]" in header and "T_delta [N m]" in header  # units in the header
    logs = []
    for name in names[2:]:  # the user's logger: other names, degrees, km/h, milliseconds
        rows = list(csv.reader((folder / "csv" / name).open()))
        hdr, data = rows[1], np.array(rows[2:], float)

        def col(h, hdr=hdr, data=data):
            return data[:, hdr.index(h)]

        table = np.column_stack([
            1000 * col("t [s]"), np.degrees(col("phi [rad]")), np.degrees(col("delta [rad]")),
            np.degrees(col("phidot [rad/s]")), np.degrees(col("deltadot [rad/s]")),
            3.6 * col("v [m/s]"), col("T_delta [N m]"),
        ])  # fmt: skip
        log = folder / f"log_{name}"
        with log.open("w") as fh:
            fh.write("time_ms,roll,steer,roll_rate,steer_rate,speed_kmh,torque\n")
            np.savetxt(fh, table, delimiter=",", fmt="%.17g")
        logs.append(log.name)
    argv = [
        "identify", *logs, "--format", "csv", "--method", "pem", "--json", "--time", "time_ms",
        "--columns", "phi=roll,delta=steer,phidot=roll_rate,deltadot=steer_rate,v=speed_kmh,"
        "T_delta=torque",
        "--units", "phi=deg,delta=deg,phidot=deg/s,deltadot=deg/s,v=km/h,t=ms",
    ]  # fmt: skip
    rc, out_csv, err = _run(argv, folder)
    assert rc == 0, err
    rc, out_h5, err = _run(["identify", "runs.h5", "--method", "pem", "--json"], folder)
    assert rc == 0, err
    from_csv, from_h5 = _eigs(out_csv), _eigs(out_h5)
    assert sorted(from_csv) == sorted(from_h5) == [4.0, 5.0]
    from bikeid.experiments.testbed.accuracy import eigen_tolerance
    from bikeid.sim.linear import eigenvalues, match_eigenvalues
    from bikeid.sim.parameters import benchmark

    for v in (4.0, 5.0):
        a = match_eigenvalues(from_csv[v], from_h5[v])
        np.testing.assert_allclose(a, from_h5[v], rtol=0, atol=1e-6)
        truth = eigenvalues(benchmark(), v)
        got = match_eigenvalues(from_csv[v], truth)
        assert np.all(np.abs(got - truth) <= [eigen_tolerance(z) for z in truth]), (got, truth)


def test_csv_format_needs_a_column_mapping(folder):
    rc, _, err = _run(["identify", "runs.h5", "--format", "csv"], folder)
    assert rc == 3 and "--columns" in err and len(err.strip().splitlines()) == 1, err


def test_export_refuses_a_link_at_the_output(folder):
    (folder / "precious.txt").write_text("keep")
    link = folder / "one.csv"
    link.symlink_to(folder / "precious.txt")
    rc, _, err = _run(["export", "runs.h5", "--run", "v4", "--out", "one.csv"], folder)
    assert rc == 3 and "symbolic link" in err, err
    assert (folder / "precious.txt").read_text() == "keep"


@pytest.mark.parametrize(
    "extra",
    [
        ["--method", "direct", "--bicycle", "benchmark"],
        ["--method", "pem", "--speed-parameterized"],
        ["--method", "pem", "--outputs", "phi,delta"],
    ],
)
def test_identify_out_then_load_model(folder, extra):
    """``identify --out``: the saved model loaded in Python has exactly the eigenvalues the
    same command printed (JSON floats are repr round trips, so equality is exact), the
    settings asked for, and the SHA-256 of the data file as hashlib computes it."""
    import hashlib

    from bikeid.ident import read_model_file

    rc, out, err = _run(["identify", "runs.h5", *extra, "--json", "--out", "m.json"], folder)
    assert rc == 0, err
    res = json.loads(out)
    printed = _eigs(out)
    files = [folder / f for f in res["model_files"]]
    assert len(files) == (2 if "--outputs" in extra else 1)
    raw = (folder / "runs.h5").read_bytes()
    for f in files:
        mf = read_model_file(f)
        assert mf.provenance == (
            {"path": "runs.h5", "size": len(raw),  # relative to the command's folder
             "sha256": hashlib.sha256(raw).hexdigest()},
        )  # fmt: skip
        assert mf.settings["method"] == extra[1] and mf.settings["outputs"] == res["outputs"]
        for v in mf.speeds if mf.kind != "canonical-pem" else (mf.model.speed,):
            eig = mf.model.eigenvalues() if mf.kind == "canonical-pem" else mf.model.eigenvalues(v)
            got = sorted(np.asarray(eig, complex), key=lambda c: (c.real, c.imag))
            assert np.array_equal(got, printed[v]), (got, printed[v])
    if "--outputs" in extra:
        assert mf.outputs == ("phi", "delta") and mf.model.K.shape == (4, 2)
    for f in files:
        f.unlink()


@pytest.mark.parametrize(
    "extra, words",
    [
        (["--method", "direct", "--outputs", "phi,delta"], "direct least squares needs"),
        (["--method", "pem", "--outputs", "phidot,deltadot"], "needs phi and delta"),
        (["--method", "pem", "--outputs", "phi,delta,yaw"], "give measured states"),
        (["--method", "pem", "--input", "phi"], "not a torque"),
        (["--method", "pem", "--input", "hand_torque"], "has no signal 'hand_torque'"),
        (["--method", "pem", "--out", "."], "is a folder"),
    ],
)
def test_identify_refuses_impossible_choices(folder, extra, words):
    rc, _, err = _run(["identify", "runs.h5", *extra], folder)
    assert rc == 3 and words in err and len(err.strip().splitlines()) == 1, err


SBW = (
    Path(
        __import__("os").environ.get(
            "BIKEID_DATA", Path(__file__).resolve().parents[4] / "shared/data"
        )
    )
    / "tudelft-sbw"
)


@pytest.mark.skipif(not (SBW / "eigen").is_dir(), reason="steer-by-wire logs not found")
def test_identify_steer_by_wire_logs(tmp_path):
    """``identify --format sbw`` on the measured free decays (4 speeds): each log is read by
    dataset.sbw_logs (through dataset.importers), cut to its settled part with v the
    treadmill speed; the treadmill settings 1.5 ... 4.5 m/s of the file names become the
    speeds, the saved model's eigenvalues equal the printed ones exactly, and the provenance
    lists each log with hashlib's SHA-256 of its bytes."""
    import hashlib

    from bikeid.dataset.sbw_logs import find_logs, load_log, settled, treadmill_speed
    from bikeid.ident import read_model_file

    argv = ["identify", str(SBW / "eigen"), "--format", "sbw", "--json", "--out", "m.json",
            "--method", "direct"]  # fmt: skip
    # push logs under the bicycle's own balance law: three of the four runs' torque is
    # feedback only (ident.informativity), so the model over speed is refused (exit 4) ...
    rc, out, err = _run(argv, tmp_path)
    assert rc == 4 and "cannot determine" in err and "2.5 m/s" in err, err
    # ... unless the user turns that check off, which the command says on stderr
    rc, out, err = _run([*argv, "--skip-check", "informativity"], tmp_path)
    assert rc == 0, err
    assert "informativity skipped" in err
    printed = _eigs(out)
    assert sorted(printed) == [1.5, 2.5, 3.5, 4.5]  # 5.4, 9, 12.6, 16.2 km/h
    mf = read_model_file(tmp_path / "m.json")
    assert mf.kind == "direct" and mf.settings["format"] == "sbw"
    for v in printed:
        got = sorted(np.asarray(mf.model.eigenvalues(v), complex), key=lambda c: (c.real, c.imag))
        assert np.array_equal(got, printed[v])
    logs = find_logs(SBW / "eigen")
    # relative to where the command ran (os.path.relpath), never the machine's absolute path
    assert [p["path"] for p in mf.provenance] == [
        Path(os.path.relpath(p.resolve(), tmp_path.resolve())).as_posix() for p in logs
    ]
    assert not any(Path(p["path"]).is_absolute() for p in mf.provenance)
    for entry, p in zip(mf.provenance, logs, strict=True):
        assert entry["sha256"] == hashlib.sha256(p.read_bytes()).hexdigest()
    full = load_log(logs[0])
    part = settled(full)
    a, b = full.meta["ramp_end_index"], full.meta["settled_end_index"]
    first = full.meta["first_index"]
    assert part.n == b - a and np.array_equal(part.t, full.t[a - first : b - first])
    assert np.array_equal(part["v"], treadmill_speed(full["v"][a - first : b - first]))
