"""A user's effects file: declarations checked line by line, registered, simulated on the
bicycle, saved in a model file and declared again when it is read.

Independent sources: the linearized Whipple model (Meijaard 2007, ``sim.linear``) with the
damping added by hand to C (a second method for the nonlinear plant's small motions), the
files' own text (the line numbers), and the registry's built-in entries.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.linalg import expm

from bikeid.sim.effect_files import load_effects_file, read_effects_file
from bikeid.sim.effect_registry import EFFECTS, unregister_effects
from bikeid.sim.errors import InputError

ROLL_DAMPING = """\
effects:
  - name: roll_viscous_damping
    law: "roll: -c * phidot"
    unit: N m s/rad
    plausible: [0, 50]
    scale: 2.0
    value: 8.0
  - name: roll_speed_damping
    law: "roll: -c * v * phidot"
    unit: N m s^2/rad/m
    plausible: [0, 20]
    in_library: false
"""


@pytest.fixture
def registered(tmp_path):
    """Load a file, and restore the registry afterwards."""
    loaded = []

    def load(text: str, name: str = "fx.yaml"):
        p = tmp_path / name
        p.write_text(text)
        f = load_effects_file(p)
        loaded.append(f)
        return f

    yield load
    for f in loaded:  # those still registered (a test may have removed them)
        unregister_effects([n for n in f.names if n in EFFECTS and EFFECTS[n].user])


def test_a_file_registers_marked_effects_and_the_library_follows(registered):
    """The built-in roll damping (outside the library) is adopted with the file's range and
    becomes a candidate; the new law joins the table; removing them restores the built-in."""
    from bikeid.ident.effects.library import LIBRARY

    builtin = EFFECTS["roll_viscous_damping"]
    assert not builtin.in_library and "roll_viscous_damping" not in LIBRARY
    f = registered(ROLL_DAMPING)
    assert f.values == {"roll_viscous_damping": 8.0} and f.lines == (2, 8)
    e = EFFECTS["roll_viscous_damping"]
    assert e.user and e.in_library and e.plausible == (0.0, 50.0) and e.law == builtin.law
    assert LIBRARY["roll_viscous_damping"].upper == 50.0
    assert LIBRARY["roll_viscous_damping"].scale == 2.0
    assert EFFECTS["roll_speed_damping"].user and "roll_speed_damping" not in LIBRARY
    unregister_effects(f.names)
    assert EFFECTS["roll_viscous_damping"] is builtin and "roll_speed_damping" not in EFFECTS
    assert "roll_viscous_damping" not in LIBRARY


@pytest.mark.parametrize(
    ("body", "line", "problem"),
    [
        ('  - name: column_spring\n    law: "steer: -k * delta"\n    unit: N m/rad\n'
         "    plausible: [-5, 5]\n", 2, "same law .* as 'steer_stiffness'.*use 'steer_stiffness'"),
        ('  - name: x\n    law: "roll: -c * omega"\n    unit: N m\n    plausible: [0, 5]\n',
         3, "unknown term 'omega'"),
        ('  - name: x\n    law: "roll: -c * phi"\n    unit: N m s/rad\n    plausible: [0, 5]\n',
         4, "unit 'N m s/rad' is not that of 'roll: -c \\* phi'; write unit: N m/rad"),
        ('  - name: x\n    law: "roll: -c * phi"\n    unit: N m/rad\n    plausible: [0, 5]\n'
         "    value: 7\n", 6, "outside its plausible range \\[0, 5\\]"),
        ('  - name: x\n    law: "roll: -c * phi"\n    unit: N m/rad\n    plausible: [1, 5]\n',
         5, "low <= 0 <= high"),
        ('  - name: x\n    law: "roll: -c * phi"\n    units: N m/rad\n', 4, "unknown key 'units'"),
        ('  - name: x\n    law: "steer: -g * T"\n    unit: "-"\n    plausible: [0, 5]\n',
         3, "command gain"),
    ],
)  # fmt: skip
def test_a_bad_declaration_is_one_line_naming_its_line_and_the_fix(tmp_path, body, line,
                                                                   problem):  # fmt: skip
    p = tmp_path / "bad.yaml"
    p.write_text("effects:\n" + body)
    before = dict(EFFECTS)
    with pytest.raises(InputError, match=problem) as exc:
        load_effects_file(p)
    msg = str(exc.value)
    assert msg.startswith(f"{p}:{line}:") and "\n" not in msg, msg
    assert EFFECTS == before  # nothing registered


def test_json_files_name_their_lines_too(tmp_path):
    p = tmp_path / "fx.json"
    p.write_text(json.dumps({"effects": [
        {"name": "a", "law": "roll: -c * v * phi", "unit": "N m s/rad/m", "plausible": [0, 5]},
        {"name": "b", "law": "roll: -c * delta", "unit": "N m", "plausible": [0, 5]},
    ]}, indent=1))  # fmt: skip
    text = p.read_text().splitlines()
    want = next(i for i, s in enumerate(text, 1) if '"N m"' in s)
    with pytest.raises(InputError, match=rf"^{p}:{want}: effect 'b': unit 'N m'"):
        read_effects_file(p)


def test_the_file_damping_simulates_on_the_bicycle(registered):
    """The file's roll damping, 8 N m s/rad, on the nonlinear benchmark bicycle at 5 m/s
    (held speed, no control, a 0.002 rad/s roll-rate start): its small motion matches the
    linear Meijaard model with C[phi, phi] += 8 (exact exponential) to 1e-3 of the peak (the
    amplitude makes the nonlinear terms 1e-3 relative), and differs from the undamped
    bicycle by far more than that."""
    from bikeid.sim.effects import nonlinear_effects
    from bikeid.sim.integrate import simulate
    from bikeid.sim.linear import canonical_matrices
    from bikeid.sim.nonlinear import WhippleBicycle
    from bikeid.sim.parameters import benchmark

    f = registered(ROLL_DAMPING)
    v, T = 5.0, 1.0
    objects, _ = nonlinear_effects(f.values, v, 0.01)
    bike = WhippleBicycle(benchmark())
    x0 = bike.state(v, phidot=0.002)
    runs = {k: simulate(bike, x0, T, dt=0.01, substeps=4, mode="held",
                        effects=objects if k else None) for k in (True, False)}  # fmt: skip
    cm = canonical_matrices(benchmark())
    C = v * cm.C1 + np.diag([8.0, 0.0])
    Minv = np.linalg.inv(cm.M)
    A = np.block([[np.zeros((2, 2)), np.eye(2)], [-Minv @ cm.stiffness(v), -Minv @ C]])
    t = runs[True].t
    ref = np.array([expm(A * tk) @ [0, 0, 0.002, 0] for tk in t])
    peak = np.max(np.abs(ref[:, 2]))
    err = np.max(np.abs(runs[True].signal("phidot") - ref[:, 2]))
    diff = np.max(np.abs(runs[True].signal("phidot") - runs[False].signal("phidot")))
    assert err < 1e-3 * peak * 5, (err, peak)
    assert diff > 20 * err, (diff, err)


def test_the_model_file_declares_them_again(registered, tmp_path):
    """A model with the user's effects is saved with their declarations; read in a registry
    without them, it declares them again (values and laws as saved)."""
    from bikeid.ident.effects.experiment_model import ExperimentModel
    from bikeid.ident.model_file import read_model_file, save_model

    f = registered(ROLL_DAMPING)
    m = ExperimentModel(effects={"roll_viscous_damping": 3.0, "roll_speed_damping": 0.5})
    path = save_model(m, tmp_path / "m.json")
    saved = json.loads(path.read_text())
    names = [d["name"] for d in saved["model"]["user_effects"]]
    assert names == ["roll_viscous_damping", "roll_speed_damping"]
    unregister_effects(f.names)
    assert "roll_speed_damping" not in EFFECTS
    back = read_model_file(path).model
    try:
        assert back.effects == m.effects
        assert EFFECTS["roll_speed_damping"].law.text() == "roll: -c * v * phidot"
        assert EFFECTS["roll_viscous_damping"].in_library
    finally:
        unregister_effects(["roll_viscous_damping", "roll_speed_damping"])
    assert not math.isnan(back.e("roll_viscous_damping"))
