"""``bikeid identify`` tests the model structure before it prints 95 % intervals.

Known both ways (ident.structure): 60 s of the exact linear plant under the roll PID at
5 m/s (the canonical model contains it: intervals kept) and the same run with the logged
torque 3 samples (30 ms) ahead of the torque that acted (a delay the canonical model lacks:
intervals withheld, the estimate printed, cause and fix named).  Truth for coverage: the
linearization (``sim.linear``).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from bikeid.controllers import UniformDither, make
from bikeid.dataset.closed_loop import simulate_run
from bikeid.dataset.store import write_runs
from bikeid.experiments.cli import main
from bikeid.sim import linear
from bikeid.sim.parameters import benchmark


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    p = benchmark()
    # seed 3: every interval of its fit covers the truth (tests/ident/test_structure.py)
    run = simulate_run(p, make("pid", p), speed=5.0, duration=60.0,
                       dither=UniformDither(1.0, seed=3), seed=3, plant="linear")  # fmt: skip
    k = 3
    sig = {n: (x[k:] if n == "T_delta" else x[:-k]) for n, x in run.signals.items()}
    late = dataclasses.replace(run, t=run.t[:-k], signals=sig, truth={}, dither=None,
                               reference=None)  # fmt: skip
    root = tmp_path_factory.mktemp("structure")
    return write_runs(root / "right.h5", [run]), write_runs(root / "delayed.h5", [late])


def _identify(capsys, *args) -> tuple[int, str]:
    rc = main(["identify", *map(str, args)])
    return rc, capsys.readouterr().out


def test_right_structure_keeps_its_intervals(files, capsys, tmp_path):
    rc, text = _identify(capsys, files[0], "--json", "--out", tmp_path / "m.json")
    doc = json.loads(text)
    assert rc == 0
    iv = doc["intervals"]
    assert iv["structure"]["passed"] is True and iv["structure"]["n_tests"] == 4
    ei = doc["per_speed"][0]["eigenvalue_intervals"]
    assert ei is not None
    truth = linear.match_eigenvalues(linear.eigenvalues(benchmark(), 5.0),
                                     [complex(e["value"]["re"], e["value"]["im"])
                                      for e in ei["eigenvalues"]])  # fmt: skip
    assert all(e["real"][0] <= t.real <= e["real"][1]
               for e, t in zip(ei["eigenvalues"], truth, strict=True))  # fmt: skip
    assert any("cannot see the bias" in n for n in iv["notes"])
    saved = json.loads((tmp_path / "m.json").read_text())
    assert saved["results"]["structure_check"]["passed"] is True


def test_rejected_structure_withholds_intervals_with_cause_and_fix(files, capsys):
    rc, text = _identify(capsys, files[1])
    assert rc == 0  # the estimate stands
    assert "identified" in text and "95 % Re" not in text
    line = next(n for n in text.splitlines() if "reject the model structure" in n)
    assert "residuals correlate with the past input" in line
    assert "no 95 % intervals are given for 5 m/s" in line
    assert "Fix:" not in line  # no remedy is printed that was not measured to cover
    rc, text = _identify(capsys, files[1], "--json")
    doc = json.loads(text)
    assert doc["per_speed"][0]["eigenvalue_intervals"] is None
    assert doc["intervals"]["structure"]["rejected_speeds"] == [5.0]
    assert np.isfinite(doc["per_speed"][0]["eigenvalues"][0]["re"])
