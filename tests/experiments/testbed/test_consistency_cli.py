"""``bikeid consistency`` end to end: a user's ``module:function`` from the current folder,
the JSON layout (one controller: ``methods``; several: ``studies``), resuming from --out,
and one-line refusals."""

from __future__ import annotations

import json
import textwrap

import pytest

from bikeid.experiments.cli import main

USER = textwrap.dedent(
    '''
    import numpy as np
    import control

    from bikeid.experiments.testbed.scenario import true_modes


    def wrong(runs, context):
        """The truth with every eigenvalue 0.2 1/s to the right (a fixed wrong model)."""
        out = {}
        for run in runs:
            w, _, cap, cas = true_modes(context.scenario)[run.speed] + 0.2
            A = np.diag([0.0, 0.0, cap.real, cas.real])
            A[:2, :2] = [[w.real, w.imag], [-w.imag, w.real]]
            out[run.speed] = control.ss(A, np.ones((4, 1)), np.eye(4), np.zeros((4, 1)))
        return out
    '''
)

ARGS = ["--speeds", "3,5", "--durations", "1,2,4", "--seeds", "8", "--no-efficiency", "--json"]


def test_user_module_runs_from_the_current_folder(tmp_path, monkeypatch, capsys):
    """``--methods usermod:wrong``: the user's fixed wrong model is ``biased`` (no scatter,
    mean error 0.2 1/s: T^2 infinite) with RMSE exactly sqrt(2 speeds x 3 x 0.2^2) = 0.490
    1/s at every length (adding 0.2 moves the three real parts, not the weave frequency);
    a rerun with --out computes nothing new."""
    (tmp_path / "usermod.py").write_text(USER)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    out = tmp_path / "study"
    assert main(["consistency", "--methods", "usermod:wrong", *ARGS, "--out", str(out)]) == 0
    res = json.loads(capsys.readouterr().out)
    m = res["methods"]["usermod:wrong"]
    assert set(m) >= {"durations", "bias", "std", "rmse", "slope", "slope_ci", "coverage",
                      "verdict"}  # fmt: skip
    assert m["verdict"] == "biased"
    assert m["rmse"] == pytest.approx([(6 * 0.2**2) ** 0.5] * 3, rel=1e-9)
    assert m["bias"]["5"]["weave_im"] == pytest.approx([0.0] * 3, abs=1e-12)
    assert m["bias"]["3"]["capsize"] == pytest.approx([0.2] * 3, rel=1e-9)
    assert (out / "consistency.json").exists() and len(list((out / "jobs").iterdir())) == 24
    assert main(["consistency", "--methods", "usermod:wrong", *ARGS, "--out", str(out)]) == 0
    assert json.loads(capsys.readouterr().out)["jobs"] == {"computed": 0, "reused": 24}


def test_several_controllers_give_a_list_of_studies(tmp_path, monkeypatch, capsys):
    (tmp_path / "usermod.py").write_text(USER)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    fig = tmp_path / "study.png"
    few = ["--speeds", "5", "--durations", "1,2,4", "--seeds", "2", "--no-efficiency", "--json"]
    argv = ["consistency", "--methods", "usermod:wrong", "--controller", "pid,pole", *few,
            "--plot", str(fig)]  # fmt: skip
    assert main(argv) == 0
    res = json.loads(capsys.readouterr().out)
    assert [s["controller"] for s in res["studies"]] == ["pid", "pole"]
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"  # one figure, a row per study
    for s in res["studies"]:  # 2 seeds: too few for a verdict, and said so
        m = s["methods"]["usermod:wrong"]
        assert m["verdict"] == "inconclusive"
        assert m["rmse"] == pytest.approx([(3 * 0.2**2) ** 0.5] * 3, rel=1e-9)


@pytest.mark.parametrize(
    ("argv", "status", "text"),
    [
        (["--methods", "nosuchmethod"], 3, "give one of"),
        (["--methods", "pem:bogus=1"], 3, "KEY=VALUE"),
        (["--methods", "nosuchmodule_q:fit"], 3, "cannot import"),
        (["--speeds", "3,3"], 2, "once"),
        (["--durations", "1e308"], 2, "out of range"),
    ],
)
def test_bad_input_is_one_line(argv, status, text, capsys):
    assert main(["consistency", *argv]) == status
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and text in err[0], err
