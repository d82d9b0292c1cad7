"""Progress of the long commands: a bar on stderr only when stderr is a terminal, nothing with
``--json`` or without a terminal (:mod:`bikeid.experiments.progress`).

A terminal is faked with a text stream whose ``isatty()`` is True.  The step counts the bar
must reach are known from the data (one PEM fit per speed plus one speed-parameterized fit;
one run per sweep speed), and the identified numbers must not depend on whether a bar was
drawn (exact equality: the same computation).
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pytest

from bikeid.experiments.cli import main
from bikeid.experiments.progress import TerminalProgress, on_terminal, terminal_progress


class FakeTerminal(io.StringIO):
    """A text stream that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def _run(argv, cwd: Path, stderr: io.StringIO) -> tuple[int, str, str]:
    out = io.StringIO()
    with contextlib.chdir(cwd), contextlib.redirect_stdout(out), contextlib.redirect_stderr(stderr):
        rc = main(argv)
    return rc, out.getvalue(), stderr.getvalue()


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """Two 12 s exact linear closed-loop runs (4 and 6 m/s) in one HDF5 file."""
    from bikeid.dataset.linear_loop import simulate
    from bikeid.dataset.store import write_runs
    from bikeid.sim.parameters import benchmark

    d = tmp_path_factory.mktemp("progress")
    runs = [simulate(benchmark(), v, duration=12.0, seed=i) for i, v in enumerate((4.0, 6.0))]
    write_runs(d / "runs.h5", runs, names=["v4", "v6"])
    return d


def test_bar_only_on_a_terminal_without_json():
    """Known both ways: a terminal gets a bar; a file gets plain stage lines (or nothing
    with lines=False); --json or --quiet nothing anywhere."""
    from bikeid.experiments.progress import LineProgress

    assert on_terminal(stream=FakeTerminal()) is True
    assert on_terminal(stream=io.StringIO()) is False
    assert on_terminal(json_output=True, stream=FakeTerminal()) is False
    assert terminal_progress("x", stream=io.StringIO(), lines=False) is None
    assert terminal_progress("x", json_output=True, stream=FakeTerminal()) is None
    assert terminal_progress("x", quiet=True, stream=FakeTerminal()) is None
    assert terminal_progress("x", quiet=True, stream=io.StringIO()) is None
    log = io.StringIO()
    lines = terminal_progress("fits", stream=log)
    assert isinstance(lines, LineProgress)
    lines(0, 2, "PEM at 4 m/s")
    lines(0, 2, "PEM at 4 m/s")  # the same step again: no second line
    lines(1, 2, "PEM at 6 m/s")
    lines.write("wrote m.json")
    assert log.getvalue() == ("fits: [0/2] PEM at 4 m/s\nfits: [1/2] PEM at 6 m/s\n"
                              "wrote m.json\n")
    tty = FakeTerminal()
    bar = terminal_progress("fits", stream=tty, unit="fit")
    assert isinstance(bar, TerminalProgress)
    bar(1, 3, "PEM at 4 m/s")
    bar(3, 3, "done")
    bar(2, 5, "stage two")  # a new total resets the bar
    bar.write("a log line")
    bar.close()
    bar.close()  # harmless
    text = tty.getvalue()
    assert "fits" in text and "1/3" in text and "3/3" in text and "2/5" in text
    assert "PEM at 4 m/s" in text and "a log line\n" in text


def test_identify_shows_progress_on_a_terminal_only(folder):
    """``identify --method pem --speed-parameterized`` on 2 speeds: 3 fits, so the bar
    reaches 3/3 on a terminal; the printed eigenvalues equal those of the run without a
    terminal, where stderr holds one line per stage (a batch job sees what ran), and is
    empty with --quiet."""
    argv = ["identify", "runs.h5", "--method", "pem", "--speed-parameterized"]
    rc, out_tty, err_tty = _run(argv, folder, FakeTerminal())
    assert rc == 0, err_tty
    assert "identify" in err_tty and "3/3" in err_tty and "speed-parameterized" in err_tty
    rc, out_file, err_file = _run(argv, folder, io.StringIO())
    assert rc == 0, err_file
    assert "identify: [0/3] PEM at 4 m/s" in err_file and "[3/3] done" in err_file
    assert "\r" not in err_file  # lines, not a bar
    assert out_tty == out_file
    rc, out_quiet, err_quiet = _run([*argv, "--quiet"], folder, io.StringIO())
    assert rc == 0 and err_quiet == "" and out_quiet == out_file


def test_identify_json_keeps_stderr_empty_on_a_terminal(folder):
    """With --json the bar is off even on a terminal: stdout is valid JSON with one row per
    speed (4 and 6 m/s) and stderr is empty."""
    argv = ["identify", "runs.h5", "--method", "pem", "--speed-parameterized", "--json"]
    rc, out, err = _run(argv, folder, FakeTerminal())
    assert rc == 0 and err == ""
    res = json.loads(out)
    assert [row["speed"] for row in res["per_speed"]] == [4.0, 6.0]


def test_sweep_bar_on_a_terminal_only(tmp_path):
    """``bikeid sweep`` over 2 speeds (1 s runs): the bar counts 2/2 runs on a terminal;
    without one stderr holds nothing."""
    base = ["sweep", "--controller", "pid", "--speeds", "4,5", "--seeds", "0", "--duration", "1"]
    rc, _, err = _run([*base, "--out", "a.h5"], tmp_path, FakeTerminal())
    assert rc == 0, err
    assert "sweep pid" in err and "2/2" in err
    rc, _, err = _run([*base, "--out", "b.h5"], tmp_path, io.StringIO())
    assert rc == 0 and err == ""


def test_accuracy_reports_its_stages(tmp_path):
    """``run_accuracy`` for one controller and one speed: 2 stages (simulate, identify), so
    the callback sees 0/2, 1/2 and 2/2 in order; log lines go to the given ``log``."""
    from bikeid.experiments.testbed.accuracy import run_accuracy

    calls, lines = [], []
    run_accuracy(
        tmp_path, ["pid"], ["pem"], [5.0], workers=1, log=lines.append,
        progress=lambda done, total, label: calls.append((done, total, label)),
    )  # fmt: skip
    assert [(d, t) for d, t, _ in calls] == [(0, 2), (1, 2), (2, 2)]
    assert calls[0][2] == "pid: simulating 1 speed(s)" and calls[1][2] == "pid: identifying"
    assert any("pid: 1 runs ready" in line for line in lines)


def test_effect_selection_counts_its_candidate_fits():
    """``select_effects`` with 2 candidates and one round: 2 candidate fits, then the joint
    fit, so the callback sees 0/2, 1/2 (labelled by candidate) and 2/2; the verdict is that
    of the injected effect (as in tests/ident/effects/test_diagnostics.py, here on 2 decays per
    speed)."""
    from bikeid.ident.effects.experiment_model import ExperimentModel
    from bikeid.ident.effects.selection import select_effects
    from bikeid.ident.effects.synthetic_decays import synthetic_windows

    truth = ExperimentModel(effects={"steer_viscous_damping": 0.4})
    ws = synthetic_windows(truth, [1.5, 3.5], 2, seed=1)
    calls = []
    res = select_effects(
        ExperimentModel(), ws, candidates=["steer_viscous_damping", "command_gain"],
        max_effects=1, progress=lambda d, t, label: calls.append((d, t, label)),
    )  # fmt: skip
    assert calls == [
        (0, 2, "round 1: steer_viscous_damping"),
        (1, 2, "round 1: command_gain"),
        (2, 2, "joint fit"),
    ]
    assert res.verdict[0] == "steer_viscous_damping"
