"""The plant commands as a new user runs them (subprocess, installed console script)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

BIN = Path(sys.executable).parent / "bikeid"


def run(*args, check=True):
    cmd = [str(BIN)] if BIN.exists() else [sys.executable, "-m", "bikeid.experiments.cli"]
    env = os.environ | {"MPLBACKEND": "Agg"}
    res = subprocess.run(cmd + list(args), capture_output=True, text=True, env=env, timeout=300)
    if check:
        assert res.returncode == 0, res.stderr
    return res


def test_critical_speeds_text_shows_published_values():
    """Meijaard 2007 Table 2(a): v_w = 4.2924, v_c = 6.0243 m/s (4 decimals printed)."""
    out = run("critical-speeds", "--bicycle", "benchmark").stdout
    assert "v_w = 4.2924 m/s" in out
    assert "v_c = 6.0243 m/s" in out
    assert "v_d = 0.6843 m/s" in out


def test_critical_speeds_json():
    """JSON keys of the issue, values to 1e-10 of the exact-arithmetic speeds."""
    data = json.loads(run("critical-speeds", "--bicycle", "benchmark", "--json").stdout)
    assert abs(data["v_d"] - 0.68428307889245579629) < 1e-10
    assert abs(data["v_w"] - 4.2923825363411039587) < 1e-10
    assert abs(data["v_c"] - 6.0242620153883588899) < 1e-10


def test_linearize_json_eigenvalues():
    """Eigenvalues at 5 m/s equal Meijaard Table 2 (1e-11)."""
    data = json.loads(run("linearize", "--bicycle", "benchmark", "--speed", "5", "--json").stdout)
    ev = sorted(complex(e["re"], e["im"]).real for e in data["eigenvalues"])
    ref = sorted([-14.07838969279820, -0.77534188219585, -0.77534188219585, -0.32286642900409])
    assert all(abs(a - b) < 1e-11 for a, b in zip(ev, ref, strict=True))
    assert data["M"][0][1] == pytest.approx(2.31941332208709, abs=1e-13)


def test_eig_json_and_plot(tmp_path):
    png = tmp_path / "eig.png"
    data = json.loads(
        run(
            "eig", "--bicycle", "benchmark", "--speeds", "0:10:0.5", "--json", "--plot", str(png)
        ).stdout
    )
    assert len(data["speeds"]) == 21 and png.stat().st_size > 10_000
    k = data["speeds"].index(5.0)
    row = zip(data["eigenvalues"][k], data["labels"], strict=True)
    weave = [complex(e["re"], e["im"]) for e, lab in row if lab == "weave"]
    assert abs(weave[0].real + 0.77534188219585) < 1e-11  # Table 2, v = 5


@pytest.mark.parametrize(
    ("args", "code", "message"),
    [
        # exit status 3: invalid input (a bicycle that does not exist); 2: a bad option value
        (("critical-speeds", "--bicycle", "Penny"), 3, "unknown bicycle 'Penny'"),
        (("eig", "--speeds", "10:0:1"), 2, "need start <= stop"),
        (("eig", "--speeds", "a:b"), 2, "is not start:stop:step"),
        (("eig", "--speeds", "0:1e9:1"), 2, "at most 1,000,000"),
        (("eig", "--speeds", "0:5000:10"), 2, "values must be <= 100"),
        (("linearize", "--speed", "nan"), 2, "'nan' is not finite"),
        (("critical-speeds", "--bicycle", "missing.yaml"), 3, "does not exist"),
    ],
)
def test_bad_input_is_one_line_error(args, code, message):
    res = run(*args, check=False)
    assert res.returncode == code
    assert message in res.stderr
    assert "Traceback" not in res.stderr and len(res.stderr.strip().splitlines()) == 1


def test_adjusted_bicycle_value_is_a_note_with_its_consequence():
    """Browser's pendulum-measured IByy = 1.3164 kg m^2 breaks the triangle inequality; the
    bound is the sum of its x-z principal moments (0.4806 + 0.8058 = 1.2864, from the
    shipped IBxx 0.5296, IBzz 0.7568, IBxz -0.1163), a change of -2.3 %.  ``eig`` says so in
    one note line on stderr, no Python warning; and the note's claim that the linear model
    does not depend on IByy holds: the eigenvalues with IByy at the other end of its range
    are the same."""
    import numpy as np

    from bikeid.sim.linear import eigenvalues
    from bikeid.sim.parameters import ParameterAdjusted, by_name

    res = run("eig", "--bicycle", "Browser", "--speeds", "5:5:1", "--json")
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("note: bicycle 'Browser'"), res.stderr
    principal = np.linalg.eigvalsh(np.array([[0.5296, -0.1163], [-0.1163, 0.7568]]))
    for text in ("IByy = 1.3164 kg m^2", f"uses IByy = {principal.sum():.5g}",
                 f"({100 * (principal.sum() - 1.3164) / 1.3164:+.1f} %)",
                 "eigenvalues and critical speeds unchanged"):  # fmt: skip
        assert text in lines[0], text
    assert "Warning" not in res.stderr
    with pytest.warns(ParameterAdjusted, match=r"uses IByy = 1\.2864 \(-2\.3 %\)"):
        p = by_name("Browser")
    other = p.replace(IByy=float(principal[1] - principal[0]))  # the range's lower end
    np.testing.assert_array_equal(np.sort_complex(eigenvalues(p, 5.0)),
                                  np.sort_complex(eigenvalues(other, 5.0)))  # fmt: skip
    printed = json.loads(res.stdout)["eigenvalues"][0]
    got = np.sort_complex([complex(z["re"], z["im"]) if isinstance(z, dict) else complex(z)
                           for z in printed])  # fmt: skip
    np.testing.assert_allclose(got, np.sort_complex(eigenvalues(p, 5.0)), rtol=1e-12)
