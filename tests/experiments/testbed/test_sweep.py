"""Closed-loop runs and sweeps: what the controller saw is what is stored, held speed, falls,
determinism across worker counts and Dask, resume after SIGKILL, and the stabilization table.

Sweeps here are tiny (a few speeds, seconds of simulated time) so the file runs in about a
minute on 2 cores.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest

from bikeid.controllers.excitation import ChirpReference, UniformDither
from bikeid.controllers.pid import PID
from bikeid.controllers.registry import STUDY_CONTROLLERS
from bikeid.dataset.closed_loop import simulate_run
from bikeid.dataset.sensors import Channel, Sensors
from bikeid.dataset.store import list_runs, read_run, read_runs, write_runs
from bikeid.experiments.cli import main
from bikeid.experiments.testbed.sweep import (
    SweepSpec,
    Task,
    _lock,
    parts_dir,
    run_seed,
    run_sweep,
    simulate_task,
    stabilization_table,
)
from bikeid.sim.conventions import MEASURED
from bikeid.sim.parameters import benchmark

ROOT = Path(__file__).resolve().parents[3]


def pid_run(**kw):
    opts = dict(
        duration=3.0,
        reference=ChirpReference(0.05, 0.05, 0.5, 3.0),
        dither=UniformDither(1.0, 0.01, 4),
        sensors=Sensors({**Sensors.default().channels, "phi": Channel(1e-3, 2e-3, 1.01, 1e-4)}),
        seed=9,
    )
    opts.update(kw)
    return simulate_run(benchmark(), PID(sample_time=0.01), 4.0, **opts)


def test_run_records_what_the_controller_saw():
    """Replaying the stored *measured* signals through a fresh controller reproduces the
    stored torque minus dither exactly (same floating-point operations), so the controller
    was fed the measured, not the true, signals; and the stored noise is the sensor model's."""
    run = pid_run()
    assert run.n == 301 and run.dt == pytest.approx(0.01)
    ctrl = PID(sample_time=0.01, reference=ChirpReference(0.05, 0.05, 0.5, 3.0))
    replay = [
        ctrl(t, [run.signals[k][i] for k in MEASURED]) + run.dither[i] for i, t in enumerate(run.t)
    ]
    np.testing.assert_array_equal(replay, run["T_delta"])
    # measured = Sensors.measure applied to the stored truth, bit for bit
    sensors = Sensors.from_dict(run.meta["sensors"])
    _, meas, _ = sensors.measure(run.t, {k: run.truth[k] for k in MEASURED}, seed=9)
    for k in MEASURED:
        np.testing.assert_array_equal(meas[k], run.signals[k])
    assert not np.array_equal(run.signals["phi"], run.truth["phi"])
    # no input effects: logged command = torque applied by the plant
    np.testing.assert_array_equal(run.true("T_delta"), run["T_delta"])


def test_held_speed_and_metadata():
    run = pid_run()
    # held mode: the ideal drive keeps v = -rR u6 constant (round-off)
    np.testing.assert_allclose(run.true("v"), 4.0, rtol=0, atol=1e-12)
    m = run.meta
    assert m["bikeid_version"] == version("bikeid")
    assert m["bicycle"]["parameters"] == benchmark().as_dict()
    assert m["controller"]["name"] == "pid" and m["controller"]["sample_time"] == 0.01
    assert m["seed"] == 9 and m["speed"] == 4.0 and m["fell_at"] is None
    assert m["dither"] == {"name": "uniform", "amplitude": 1.0, "hold": 0.01, "seed": 4}
    assert m["reference"]["name"] == "chirp"
    np.testing.assert_array_equal(run.reference, ChirpReference(0.05, 0.05, 0.5, 3.0).sample(run.t))


def test_lateral_force_is_logged_like_a_load_cell():
    """The applied lateral force (Moore & Hubbard's perturbation F) is a measured signal;
    with an ideal F channel the log equals the applied force exactly (same samples)."""
    from bikeid.controllers.excitation import LateralForcePulses

    pulses = LateralForcePulses(peak=50.0, duration=0.2, mean_gap=1.0, min_gap=0.5, seed=3)
    run = simulate_run(
        benchmark(), PID(sample_time=0.01), 4.0, duration=5.0, sensors=Sensors.ideal(),
        lateral_force=pulses,
    )  # fmt: skip
    expected = np.array([pulses(tk) for tk in run.t])
    assert np.abs(expected).max() > 10.0  # some pushes happened
    np.testing.assert_array_equal(run["F"], run.true("F"))
    np.testing.assert_allclose(run["F"], expected, rtol=0, atol=1e-12)


def test_fallen_run_is_kept_and_flagged():
    """Without feedback the benchmark at 2 m/s is weave-unstable (Meijaard 2007: stable only
    for 4.29 < v < 6.02 m/s), so a small initial roll rate must end in a fall."""
    run = simulate_run(
        benchmark(), PID(0.0, 0.0, 0.0, sample_time=0.01), 2.0, duration=20.0,
        sensors=Sensors.ideal(), initial={"phidot": 0.3},
    )  # fmt: skip
    fell = run.meta["fell_at"]
    assert fell is not None and 0 < fell < 20.0
    assert run.t[-1] <= fell < run.t[-1] + 0.01 + 1e-9  # truncated at the fall
    assert abs(run.true("phi")[-1]) > np.radians(30)


def test_sensor_faster_than_controller_is_refused():
    with pytest.raises(ValueError, match="faster than the controller"):
        simulate_run(benchmark(), PID(sample_time=0.01), 4.0, duration=1.0,
                     sensors=Sensors.ideal(rate=200))  # fmt: skip


SPEC = SweepSpec("pid", speeds=(2.0, 5.0, 9.0), seeds=(0, 1), duration=2.0)


def test_seed_depends_only_on_seed_speed_controller():
    seeds = {run_seed(s, v, c) for s in (0, 1) for v in (2.0, 2.5) for c in ("pid", "fuzzy")}
    assert len(seeds) == 8  # all distinct
    assert run_seed(1, 2.5, "pid") == run_seed(1, 2.5, "pid")


def test_deterministic_across_worker_counts(tmp_path):
    a = run_sweep(SPEC, tmp_path / "w1.h5", workers=1, progress=False)
    b = run_sweep(SPEC, tmp_path / "w2.h5", workers=2, progress=False)
    assert a.computed == b.computed == 6 and a.reused == 0
    assert (tmp_path / "w1.h5").read_bytes() == (tmp_path / "w2.h5").read_bytes()
    assert not parts_dir(tmp_path / "w1.h5").exists()
    names = list_runs(tmp_path / "w1.h5")
    assert names == [t.name for t in SPEC.tasks()]
    # a run does not depend on which other runs were computed: recompute one alone
    alone = simulate_task(SPEC, Task(names[3], 5.0, 1))
    stored = read_run(tmp_path / "w2.h5", names[3])
    for k in stored.signals:
        np.testing.assert_array_equal(alone.signals[k], stored.signals[k])
    assert alone.meta == stored.meta
    # second call: nothing to do, file unchanged
    before = (tmp_path / "w1.h5").read_bytes()
    again = run_sweep(SPEC, tmp_path / "w1.h5", workers=1, progress=False)
    assert again.computed == 0 and again.reused == 6
    assert (tmp_path / "w1.h5").read_bytes() == before


def test_changed_settings_and_concurrent_sweeps_are_refused(tmp_path):
    out = tmp_path / "s.h5"
    small = SweepSpec("pid", speeds=(5.0,), seeds=(0,), duration=1.0)
    run_sweep(small, out, progress=False)
    other = SweepSpec("pid", speeds=(5.0,), seeds=(0,), duration=2.0)
    with pytest.raises(ValueError, match="different settings \\(duration\\)"):
        run_sweep(other, out, progress=False)
    with _lock(parts_dir(out)), pytest.raises(ValueError, match="another sweep is writing"):
        run_sweep(small, out, progress=False)


def test_resume_after_sigkill(tmp_path):
    """Kill -9 a sweep after some runs finished; the rerun computes only the rest, the file
    is readable and byte-identical to an uninterrupted sweep."""
    args = ["--controller", "pid", "--speeds", "2:7:0.5", "--seeds", "0", "--duration", "20"]
    out = tmp_path / "killed.h5"
    parts = parts_dir(out)
    proc = subprocess.Popen(
        [sys.executable, "-m", "bikeid.experiments.cli", "sweep", *args, "--out", str(out),
         "--no-progress"],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )  # fmt: skip
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if len(list(parts.glob("*.h5"))) >= 3:
            break
        time.sleep(0.01)
    assert proc.poll() is None, f"sweep ended before it could be killed: {proc.stderr.read()}"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    proc.stderr.close()
    finished = len(list(parts.glob("*.h5")))
    assert 3 <= finished < 11 and not out.exists()
    # a torn part (e.g. a disk error) and a stale temporary file must not break the rerun
    victim = sorted(parts.glob("*.h5"))[0]
    victim.write_bytes(victim.read_bytes()[:1000])
    (parts / ".leftover.h5.abc.tmp").write_bytes(b"partial")
    log: list[str] = []
    spec = SweepSpec("pid", tuple(np.arange(2, 7.01, 0.5)), (0,), 20.0)
    report = run_sweep(spec, out, workers=1, progress=False, log=log.append)
    assert report.total == 11
    assert report.reused == finished - 1 and report.computed == 11 - finished + 1
    assert any("discarding damaged part" in m for m in log)
    assert not parts.exists()
    clean = tmp_path / "clean.h5"
    assert main(["sweep", *args, "--out", str(clean), "--workers", "2", "--no-progress"]) == 0
    assert out.read_bytes() == clean.read_bytes()
    assert len(read_runs(out)) == 11


def test_dask_local_cluster_matches_local(tmp_path):
    from distributed import Client, LocalCluster

    local = run_sweep(SPEC, tmp_path / "local.h5", workers=2, progress=False)
    with LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                      dashboard_address=None) as cluster:  # fmt: skip
        address = cluster.scheduler_address
        with Client(cluster):
            report = run_sweep(SPEC, tmp_path / "dask.h5", dask=address, progress=False)
    assert report.computed == local.computed == 6
    assert (tmp_path / "dask.h5").read_bytes() == (tmp_path / "local.h5").read_bytes()


def test_stabilization_table_analytic_cases():
    """Upright equilibrium: zero reference, no dither, ideal sensors -> the bicycle stays
    upright, RMS error and peak torque 0 for every controller, up to the round-off of the
    nonlinear equations at the upright state (observed ~1e-15 deg; bound 1e-9)."""
    rows = stabilization_table(
        [3.0, 6.0], duration=2.0, progress=False, reference="zero", dither=0.0, sensors="ideal"
    )
    assert [(r["controller"], r["speed"]) for r in rows] == [
        (c, v) for c in STUDY_CONTROLLERS for v in (3.0, 6.0)
    ]
    for r in rows:
        assert r["upright"] and r["error"] is None
        assert r["rms_error_deg"] < 1e-9 and r["peak_torque"] < 1e-9


def test_stabilization_cli_writes_json_and_markdown(tmp_path, capsys):
    import json

    out = tmp_path / "stab"
    assert main(["stabilization", "--speeds", "5", "--duration", "3", "--controllers", "pid",
                 "--out", str(out), "--no-progress"]) == 0  # fmt: skip
    data = json.loads((tmp_path / "stab.json").read_text())
    (row,) = data["rows"]
    assert row["upright"] and row["speed"] == 5.0
    # the dither alone is +-1 N m, so the peak applied torque must exceed its largest draw
    assert row["peak_torque"] > 0.9
    assert "| pid | 5 | yes |" in (tmp_path / "stab.md").read_text()
    assert "| pid | 5 | yes |" in capsys.readouterr().out


def test_cli_bad_input(capsys, tmp_path):
    assert main(["sweep", "--controller", "nope", "--out", str(tmp_path / "x.h5")]) == 2
    assert "unknown controller 'nope'" in capsys.readouterr().err
    assert main(["sweep", "--controller", "pid", "--out", str(tmp_path / "x.csv")]) == 3
    assert "must end in .h5" in capsys.readouterr().err
    assert (
        main(["sweep", "--controller", "pid", "--seeds", "0.5,1", "--out", str(tmp_path / "y.h5")])
        == 2
    )
    assert "seeds must be integers" in capsys.readouterr().err
    from bikeid.experiments.cli.data import _seeds

    assert _seeds("0:4") == (0, 1, 2, 3, 4) and _seeds("3,7") == (3, 7)


def test_store_reads_sweep_written_by_other_tools(tmp_path):
    """A sweep file is an ordinary run file: write_runs of its runs gives the same data."""
    run_sweep(SweepSpec("fuzzy", (4.0,), (0,), 1.0), tmp_path / "f.h5", progress=False)
    runs = read_runs(tmp_path / "f.h5")
    write_runs(tmp_path / "g.h5", runs)
    for a, b in zip(runs, read_runs(tmp_path / "g.h5"), strict=True):
        assert a.meta == b.meta
        for k in a.signals:
            np.testing.assert_array_equal(a.signals[k], b.signals[k])
