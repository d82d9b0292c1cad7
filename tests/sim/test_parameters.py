"""Parameter sets: constructors, validation messages and the Moore (2012) conversion."""

import json
import math
import warnings

import numpy as np
import pytest

from bikeid.sim import parameters
from bikeid.sim.parameters import BicycleParameters

# Moore (2012) parameters of the benchmark as produced by symbrim/bicycleparameters
# (whipple-benchmarks.md section 1.4, 16 digits).
MOORE_REF = dict(
    rf=0.35, rr=0.3, d1=0.9534570696121849, d2=0.2676445084476887, d3=0.03207142672761929,
    l1=0.4707271515135145, l2=-0.47792881146460797, l3=-0.00597083392418685,
    l4=-0.3699518200282974, mc=85, md=2, me=4, mf=3, id11=0.0603, id22=0.12, if11=0.1405,
    if22=0.28, ic11=7.178169776497895, ic22=11, ic33=4.821830223502103,
    ic31=3.8225535938357873, ie11=0.05841337700152972, ie22=0.06,
    ie33=0.007586622998470264, ie31=0.009119225261946298, g=9.81,
)  # fmt: skip


def test_benchmark_to_moore():
    """Agreement to 1e-14: same closed-form formulas, double precision round-off."""
    got = parameters.benchmark().to_moore()
    for key, ref in MOORE_REF.items():
        assert got[key] == pytest.approx(ref, rel=1e-14, abs=1e-15), key


def test_shipped_benchmark_file_is_rounded():
    """bicycleparameters' Benchmark file rounds IHxx, IHzz, IHxz (whipple-benchmarks.md):
    the exact constructor must differ from it there and agree elsewhere."""
    exact = parameters.benchmark().as_dict()
    shipped = parameters.from_bicycleparameters("Benchmark").as_dict()
    assert shipped["IHxx"] == 0.0589 and exact["IHxx"] == 0.05892
    same = {k for k in exact if k not in ("IHxx", "IHzz", "IHxz", "lam")}
    assert all(shipped[k] == pytest.approx(exact[k], rel=1e-12) for k in same)


def test_every_shipped_bicycle_loads():
    """Every bicycleparameters bicycle loads by name, case-insensitively."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name in parameters.known_names():
            p = parameters.by_name(name.upper())
            assert p.mB > 0


def test_clipped_measured_iyy_warns():
    """Browser's pendulum-measured IByy = 1.3164 breaks the triangle inequality; the
    bound is the sum of the x-z principal moments (0.4806 + 0.8058, analytic)."""
    with pytest.warns(UserWarning, match="IByy"):
        p = parameters.from_bicycleparameters("Browser")
    principal = np.linalg.eigvalsh(np.array([[0.5296, -0.1163], [-0.1163, 0.7568]]))
    assert p.IByy == pytest.approx(principal.sum(), rel=1e-12)


def _bad(**changes):
    return parameters.benchmark().as_dict() | changes


@pytest.mark.parametrize(
    ("changes", "pattern"),
    [
        ({"mB": 0.0}, r"mB=0.0: rear body mass must be positive"),
        ({"mF": -3.0}, r"mF=-3.0: front wheel mass must be positive"),
        ({"rR": 0.0}, r"rR=0.0: rear wheel radius must be positive"),
        ({"rF": -0.35}, r"rF=-0.35"),
        ({"w": 0.0}, r"w=0.0: wheelbase must be positive"),
        ({"c": float("nan")}, r"'c' is nan: every parameter must be finite"),
        ({"IBxx": float("inf")}, r"'IBxx' is inf"),
        ({"lam": math.pi / 2}, r"lam=.*strictly between -pi/2 and pi/2"),
        ({"c": 2.0}, r"c=2.0: trail magnitude must be smaller than the wheelbase"),
        ({"zB": 0.3}, r"zB=0.3: rear body mass centre must be above the ground"),
        ({"zH": 0.1}, r"zH=0.1: front frame mass centre must be above the ground"),
        ({"IBxz": 6.0}, r"IBxz=6.0: rear body inertia tensor is not positive definite"),
        ({"IHxx": -0.05}, r"IHxx=-0.05: front frame moments of inertia must be positive"),
        ({"IByy": 13.0}, r"rear body principal moments .* triangle inequality"),
        ({"IRyy": 0.2}, r"IRyy=0.2: rear wheel breaks the triangle inequality"),
        ({"IFxx": 0.0}, r"IFxx=0.0: front wheel diametral inertia must be positive"),
        ({"g": "heavy"}, r"'g' must be a real number"),
    ],
)
def test_invalid_parameters_raise_clear_error(changes, pattern):
    with pytest.raises(ValueError, match=pattern):
        BicycleParameters(**_bad(**changes))


def test_replace_validates():
    with pytest.raises(ValueError, match="mH"):
        parameters.benchmark().replace(mH=-1.0)


def test_parameter_files_roundtrip(tmp_path):
    """JSON and YAML files reproduce the object exactly; unknown and missing keys fail."""
    import yaml

    p = parameters.benchmark()
    jf = tmp_path / "bike.json"
    jf.write_text(json.dumps(p.as_dict() | {"name": "mine"}))
    assert parameters.from_file(jf).as_dict() == p.as_dict()
    assert parameters.by_name(str(jf)).name == "mine"
    yf = tmp_path / "bike.yaml"
    yf.write_text(yaml.safe_dump(p.as_dict()))
    assert parameters.from_file(yf).as_dict() == p.as_dict()
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(p.as_dict() | {"trail": 0.1}))
    with pytest.raises(ValueError, match=r"unknown parameters \['trail'\]"):
        parameters.from_file(bad)
    d = p.as_dict()
    del d["mR"]
    bad.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=r"missing parameters \['mR'\]"):
        parameters.from_file(bad)
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        parameters.from_file(bad)
    with pytest.raises(ValueError, match="does not exist"):
        parameters.from_file(tmp_path / "nope.yaml")


def test_unknown_name_lists_choices():
    with pytest.raises(ValueError, match=r"unknown bicycle 'Penny'.*benchmark.*Browser"):
        parameters.by_name("Penny")


def test_steer_by_wire_matches_readme():
    """Values of the tudelft-sbw README (lam = 18.2 deg)."""
    p = parameters.steer_by_wire()
    assert p.lam == pytest.approx(math.radians(18.2))
    assert (p.w, p.c, p.mR, p.mB, p.rF) == (1.036, 0.0803, 10.12, 20.9, 0.3498)
