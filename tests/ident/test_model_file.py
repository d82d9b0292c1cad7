"""ident.model_file: save -> load is exact for every kind; bad files are refused clearly.

The reference for every round trip is the saved model itself: a float64 written with
Python's shortest round-trip ``repr`` and parsed back is the same float (IEEE 754 and
Python's float formatting guarantee), so every comparison here is exact equality (no
tolerance): parameters by ``np.array_equal`` on their bit patterns, eigenvalues and
open-loop simulations (:func:`bikeid.ident.validate.simulation`) by ``np.array_equal``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.dataset import files
from bikeid.dataset.linear_loop import simulate
from bikeid.ident import greybox, load_model, pem, read_model_file, save_model
from bikeid.ident.direct import identify
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.model_file import model_from_text, model_json
from bikeid.ident.signals import prepare
from bikeid.ident.validate import simulation
from bikeid.sim.errors import InputError
from bikeid.sim.parameters import benchmark
from bikeid.sim.sampling import zoh

P = benchmark()


@pytest.fixture(scope="module")
def runs():
    """Short noisy closed-loop runs at two speeds (noise: covariances are not zero)."""
    return [
        simulate(
            P, v, duration=8.0, seed=i, dither=1.0, dither_hold=5, angle_noise=1e-3, rate_noise=1e-2
        )
        for i, v in enumerate((3.0, 5.0))
    ]


@pytest.fixture(scope="module")
def models(runs):
    per = {round(r.speed, 6): pem.fit(r, multistart=False) for r in runs}
    speed = pem.fit_speed_model(runs, per_speed=per, max_nfev=5, passes=1)
    direct = identify([prepare(r, cutoff=None, derivative="interval") for r in runs], P)
    exp = ExperimentModel(effects={"input_delay": 0.0123456789012345, "steer_viscous_damping": 0.1})
    grey = greybox.fit(runs, reference=P, max_nfev=20, passes=1)
    return {
        "canonical-pem": per[3.0],
        "speed-canonical-pem": speed,
        "direct": direct,
        "experiment-model": exp,
        "greybox": grey,
    }


def _without_structure(m):
    """The model (and its per-speed fits) without the attached structure check."""
    if not hasattr(m, "structure"):
        return m
    if hasattr(m, "per_speed"):
        per = {v: dataclasses.replace(pm, structure=None) for v, pm in m.per_speed.items()}
        return dataclasses.replace(m, structure=None, per_speed=per)
    return dataclasses.replace(m, structure=None)


def _same(a, b, where="model") -> None:
    """Exact equality of two saved objects, float bit patterns included (-0.0 != 0.0)."""
    if dataclasses.is_dataclass(a):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            _same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, dict):
        assert list(a) == list(b), where
        for k in a:
            _same(a[k], b[k], f"{where}[{k}]")
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, (np.ndarray, float, np.floating)):
        x, y = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        assert x.shape == y.shape and np.array_equal(x.view(np.int64), y.view(np.int64)), where
    else:
        assert a == b, where


@pytest.mark.parametrize(
    "kind", ["canonical-pem", "speed-canonical-pem", "direct", "experiment-model", "greybox"]
)
def test_round_trip_bit_for_bit(kind, models, runs, tmp_path):
    """Every field, the eigenvalues and a simulation of the loaded model equal the saved
    model's exactly (module docstring: exact float round trip, so no tolerance)."""
    m = models[kind]
    path = save_model(m, tmp_path / "m.json", settings={"method": kind})
    back = load_model(path)
    # the attached structure check is a verdict on the fitted runs, saved by identify as
    # results.structure_check, not a field of the saved model
    _same(_without_structure(m), back)
    r = runs[0]
    u, y = r["T_delta"], np.column_stack([r["phi"], r["delta"]])
    if kind == "canonical-pem":
        assert np.array_equal(back.eigenvalues(), m.eigenvalues())
        Ad, Bd, C, _ = m.predictor()
        Ad2, Bd2, C2, _ = back.predictor()
        sims = [
            simulation(A, B, Cm, u, np.column_stack([r[o] for o in m.outputs]))
            for A, B, Cm in ((Ad, Bd, C), (Ad2, Bd2, C2))
        ]
    elif kind == "speed-canonical-pem":
        for v in (2.0, 3.0, 4.3, 5.0, 9.0):
            assert np.array_equal(back.eigenvalues(v), m.eigenvalues(v))
        sims = []
        for mm in (m, back):
            Ad, Bd, C, _ = mm.at(4.0).predictor()
            sims.append(simulation(Ad, Bd, C, u, np.column_stack([r[o] for o in mm.outputs])))
    elif kind in ("direct", "greybox"):
        sims = []
        for mm in (m, back):
            assert np.array_equal(mm.eigenvalues(5.0), m.eigenvalues(5.0))
            ss = mm.state_space(5.0, inputs=("T_delta",))
            Ad, Bd = zoh(np.asarray(ss.A), np.asarray(ss.B), r.dt)
            sims.append(simulation(Ad, Bd, np.asarray(ss.C)[:2], u, y))
        if kind == "greybox":  # what identify prints: critical speeds, theta covariance
            assert back.critical_speeds() == m.critical_speeds()
            assert np.array_equal(back.theta_covariance(4.0), m.theta_covariance(4.0))
            assert isinstance(back, greybox.GreyboxModel) and back.speeds == (3.0, 5.0)
    else:
        assert np.array_equal(back.eigenvalues(5.0), m.eigenvalues(5.0))
        return
    assert np.array_equal(sims[0][0], sims[1][0]) and np.array_equal(sims[0][1], sims[1][1])


def test_metadata_and_provenance(models, tmp_path):
    """Provenance hashes equal hashlib's of the files; settings, version, summary kept."""
    data = [tmp_path / "a.csv", tmp_path / "b.bin"]
    data[0].write_text("t,phi\n0,1\n")
    data[1].write_bytes(bytes(range(256)) * 1000)
    save_model(
        models["speed-canonical-pem"],
        tmp_path / "m.json",
        provenance=data,
        settings={"method": "pem", "noise_model": "free"},
    )
    mf = read_model_file(tmp_path / "m.json")
    for entry, f in zip(mf.provenance, data, strict=True):
        raw = f.read_bytes()
        assert entry == {
            "path": os.path.relpath(f.resolve()),  # relative to the working directory
            "size": len(raw),
            "sha256": hashlib.sha256(raw).hexdigest(),
        }
    assert mf.kind == "speed-canonical-pem" and mf.version == 1
    assert mf.settings == {"method": "pem", "noise_model": "free"}
    assert mf.speeds == (3.0, 5.0) and mf.inputs == ("T_delta",)
    assert mf.sample_time == models["speed-canonical-pem"].dt
    raw = json.loads((tmp_path / "m.json").read_text())
    assert raw["format"] == "bikeid-model" and raw["created"].endswith("+00:00")


finite = st.floats(allow_nan=False, allow_infinity=False, allow_subnormal=True)
#: Variances: a diagonal covariance of any finite non-negative values is positive
#: semi-definite, which a model file must hold (checked on loading).
variance = st.floats(min_value=0.0, allow_nan=False, allow_infinity=False, allow_subnormal=True)


@settings(deadline=None)  # timing is not what is tested (a loaded machine)
@given(
    theta=st.lists(finite, min_size=10, max_size=10),
    cov=st.lists(variance, min_size=10, max_size=10),
    k=st.lists(finite, min_size=8, max_size=8),
    dt=st.floats(min_value=1e-300, max_value=1e3, allow_subnormal=False),
)
def test_round_trip_property(theta, cov, k, dt):
    """Any finite float64 values (subnormal, huge, -0.0) come back with the same bits."""
    m = pem.CanonicalModel(
        theta=np.array(theta),
        covariance=np.diag(cov),
        K=np.array(k).reshape(4, 2),
        dt=dt,
        speed=4.0,
        noise_covariance=np.eye(2) * 5e-324,
        outputs=("phi", "delta"),
        x0=(np.array(theta[:4]),),
        cost=float("nan"),
    )
    _same(m, model_from_text(model_json(m)).model)


@settings(deadline=None)  # timing is not what is tested (a loaded machine)
@given(
    mats=st.lists(finite, min_size=18, max_size=18),
    cov=st.lists(variance, min_size=3, max_size=3),
    k=st.lists(finite, min_size=16, max_size=16),
    dt=st.floats(min_value=1e-300, max_value=1e3, allow_subnormal=False),
    symmetric=st.booleans(),
)
def test_greybox_round_trip_property(mats, cov, k, dt, symmetric):
    """A grey-box model of any finite values (subnormal, huge, -0.0) comes back with the
    same bits in every field: estimates, covariance, fixed values, free set, per-speed
    gains, speeds and conditioning."""
    names = ("Mpd", "K0dd", "C1dd")
    m = greybox.GreyboxModel(
        M=np.array(mats[0:4]).reshape(2, 2), C1=np.array(mats[4:8]).reshape(2, 2),
        K0=np.array(mats[8:12]).reshape(2, 2), K2=np.array(mats[12:16]).reshape(2, 2),
        g=9.81, H=np.array(mats[16:18]),
        free=dict(zip(names, mats[:3], strict=True)),
        stderr=dict(zip(names, mats[3:6], strict=True)),
        covariance=np.diag(cov), condition=mats[6],
        inflation=dict(zip(names, mats[7:10], strict=True)),
        weakest=dict(zip(names, mats[10:13], strict=True)), dropped=("K2dd",),
        fixed={"Mpp": mats[13], "K2dd": mats[14]}, symmetric=symmetric,
        K={2.0: np.array(k[:8]).reshape(4, 2), 4.5: np.array(k[8:]).reshape(4, 2)},
        dt=dt, outputs=("phi", "delta"), speeds=(2.0, 4.5),
        noise_covariance=np.eye(2) * 5e-324, cost=float("nan"), nfev=7, notes=("a", "b"),
    )  # fmt: skip
    _same(m, model_from_text(model_json(m)).model)


def test_greybox_file_refuses_inconsistent_gains(models):
    """One gain per speed in the file's order: a missing gain is named, one line."""
    obj = json.loads(model_json(models["greybox"]))
    obj["model"]["K"] = obj["model"]["K"][:1]
    with pytest.raises(InputError, match=r"'model\.K'.*one gain per speed") as exc:
        model_from_text(json.dumps(obj), "model file 'g.json'")
    assert "\n" not in str(exc.value)


def _text(models, **change) -> str:
    obj = json.loads(model_json(models["canonical-pem"]))
    for key, value in change.items():
        if value is KeyError:
            obj.pop(key)
        else:
            obj[key] = value
    return json.dumps(obj)


@pytest.mark.parametrize(
    "change, words",
    [
        ({"version": 2}, ["'version'", "upgrade bikeid"]),
        ({"version": "1"}, ["'version'"]),
        ({"version": True}, ["'version'"]),
        ({"kind": "neural-net"}, ["'kind'", "canonical-pem"]),
        ({"format": "other"}, ["'format'", "not a bikeid model file"]),
        ({"model": KeyError}, ["'model'", "missing"]),
        ({"settings": KeyError}, ["'settings'", "missing"]),
        ({"provenance": [{"path": "x", "size": 1, "sha256": "z"}]}, ["sha256"]),
        ({"outputs": ["phi"]}, ["'outputs'"]),
    ],
)
def test_refuses_bad_header(models, change, words):
    with pytest.raises(InputError) as exc:
        model_from_text(_text(models, **change), "model file 'm.json'")
    msg = str(exc.value)
    assert "\n" not in msg and all(w in msg for w in words), msg


@pytest.mark.parametrize(
    "edit, words",
    [
        (lambda s: s.pop("theta"), ["'model.theta'", "missing"]),
        (lambda s: s.update(theta=s["theta"][:9]), ["'model.theta'", "shape (9,)"]),
        (lambda s: s.update(theta=[*s["theta"][:9], "1"]), ["'model.theta'", "number"]),
        (lambda s: s.update(K=[[1.0]]), ["'model.K'"]),
        (lambda s: s.update(dt=0.0), ["'model.dt'", "positive"]),
        (lambda s: s.update(nfev=-1), ["'model.nfev'"]),
        (lambda s: s.update(outputs=["phi", "phi"]), ["'model.outputs'"]),
        (lambda s: s.update(parameter_names=["b2"]), ["'model.parameter_names'"]),
        (lambda s: s.update(cost="__1e400__"), ["'model.cost'", "finite"]),
    ],
)
def test_refuses_bad_model_fields(models, edit, words):
    obj = json.loads(model_json(models["canonical-pem"]))
    edit(obj["model"])
    with pytest.raises(InputError) as exc:
        # 1e400 is valid JSON that overflows a float64 (json.dumps cannot write it)
        model_from_text(json.dumps(obj).replace('"__1e400__"', "1e400"), "model file 'm.json'")
    assert all(w in str(exc.value) for w in words), str(exc.value)


def test_refuses_nan_truncated_non_json_missing(models, tmp_path):
    text = model_json(models["canonical-pem"])
    cases = {
        "nan.json": text.replace('"speed": 3.0', '"speed": NaN'),
        "cut.json": text[: len(text) // 2],
        "prose.json": "this is not a model\n",
        "list.json": "[1, 2]",
    }
    assert '"speed": NaN' in cases["nan.json"]
    for name, body in cases.items():
        (tmp_path / name).write_text(body)
        with pytest.raises(InputError, match=name):
            load_model(tmp_path / name)
    with pytest.raises(InputError, match="does not exist"):
        load_model(tmp_path / "absent.json")
    with pytest.raises(InputError, match="folder"):
        load_model(tmp_path)


def test_save_refuses_nan_and_keeps_existing_file(models, tmp_path, monkeypatch):
    """A failed save leaves the user's file byte for byte and no temporary file."""
    target = tmp_path / "model.json"
    target.write_text("precious\n")
    bad = dataclasses.replace(models["canonical-pem"], theta=np.full(10, np.nan))
    with pytest.raises(ValueError, match="theta"):
        save_model(bad, target)

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(files.os, "replace", broken_replace)
    with pytest.raises(OSError, match="disk full"):
        save_model(models["direct"], target)
    assert target.read_text() == "precious\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.json"]


def test_nullable_values_read_as_nan(models):
    """cost of a model derived at another speed is NaN: saved as null, read back as NaN."""
    m = models["speed-canonical-pem"].at(4.0)
    assert math.isnan(m.cost)
    obj = json.loads(model_json(m))
    assert obj["model"]["cost"] is None
    assert math.isnan(model_from_text(json.dumps(obj)).model.cost)


def test_measured_fit_file_round_trip(models, tmp_path):
    """``measured fit`` writes its model object as an experiment-model file; ``measured
    evaluate``/``report`` (bikeid.ident.effects.pipeline.model_from_json) read back the same object
    (the
    effect values bit for bit), the old plain layout is still read, and a model of another
    kind is refused naming the command that writes the right one."""
    from bikeid.ident.effects.pipeline import model_from_json, save_fit

    obj = {
        "bicycle": "steer-by-wire", "plant": "linear",
        "effects": {"steer_viscous_damping": 0.1 + 0.2, "input_delay": 5e-324},
        "fit_speeds": [1.5, 3.5], "fit_files": ["a.log.gz"],
        "fit_windows": [{"file": "a.log.gz", "start": 10, "end": 400}],
        "identification": {"verdict": "explained", "effects": [{"name": "input_delay",
                           "std": float("nan")}]},
        "decays": "listed",
    }  # fmt: skip
    save_fit(obj, tmp_path / "m.json", {"max_effects": 3}, [])
    model, back = model_from_json(tmp_path / "m.json")
    assert back["effects"] == obj["effects"] and model.effects == obj["effects"]
    assert back["plant"] == "linear" and back["fit_speeds"] == [1.5, 3.5]
    assert back["decays"] == "listed" and back["fit_windows"] == obj["fit_windows"]
    assert back["identification"]["effects"][0]["std"] is None  # NaN saved as null
    mf = read_model_file(tmp_path / "m.json")
    assert mf.kind == "experiment-model" and mf.settings["max_effects"] == 3
    (tmp_path / "old.json").write_text(json.dumps({"effects": obj["effects"], "plant": "linear"}))
    assert model_from_json(tmp_path / "old.json")[1]["effects"] == obj["effects"]
    save_model(models["direct"], tmp_path / "d.json")
    with pytest.raises(InputError, match="direct model.*measured fit"):
        model_from_json(tmp_path / "d.json")


json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), finite, st.integers(), st.text(max_size=6)),
    lambda c: st.one_of(st.lists(c, max_size=3), st.dictionaries(st.text(max_size=6), c)),
    max_leaves=8,
)


def _paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, (*prefix, i))


_SPEED_TEXT = None


@settings(deadline=None)  # the first example builds the file text (fixture warm-up)
@given(data=st.data(), value=json_values)
def test_any_damaged_field_is_a_clear_input_error(models, data, value):
    """Replace any one field of a valid speed-model file (every nesting level) by an
    arbitrary JSON value: the file either still reads or is refused with a one-line
    InputError; never another exception (a traceback)."""
    global _SPEED_TEXT
    if _SPEED_TEXT is None:
        _SPEED_TEXT = model_json(models["speed-canonical-pem"])
    obj = json.loads(_SPEED_TEXT)
    paths = list(_paths(obj))[1:]
    path = data.draw(st.sampled_from(paths))
    node = obj
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    try:
        model_from_text(json.dumps(obj), "model file 'm.json'")
    except InputError as exc:
        assert "\n" not in str(exc) and "m.json" in str(exc)


def test_a_new_method_saves_and_loads_through_its_table_entry(tmp_path, monkeypatch):
    """Adding a method is one module plus one table entry: a model class the model file has
    never heard of round-trips through save_model/load_model by the entry's codec (no edit to
    ident/model_file.py), its summary fields land at the top of the file, and a damaged
    section is one refusal naming the file and the field."""
    from dataclasses import dataclass

    from bikeid.ident import methods
    from bikeid.ident.model_file import read_model_file, save_model
    from bikeid.sim.errors import InputError

    @dataclass(frozen=True)
    class ToyModel:
        a: float
        speed: float

    codec = methods.ModelCodec(
        write=lambda m: {"a": m.a, "speed": m.speed},
        read=lambda sec: ToyModel(float(sec["a"]), float(sec["speed"])),
        summary=lambda m: {"inputs": ["T_delta"], "outputs": ["phi"], "sample_time": 0.01,
                           "speeds": [m.speed]},
    )  # fmt: skip
    entry = methods.Method("toy", "a toy", methods.fit_pem, methods.PemSettings, (ToyModel,),
                           ("toy-model",), fixed_entries=False, free_entries=False,
                           codecs={"toy-model": codec})  # fmt: skip
    monkeypatch.setitem(methods.METHODS, "toy", entry)
    path = save_model(ToyModel(0.25, 4.5), tmp_path / "toy.json")
    f = read_model_file(path)
    assert f.model == ToyModel(0.25, 4.5)
    text = json.loads(path.read_text())
    assert text["kind"] == "toy-model" and text["speeds"] == [4.5]
    text["model"] = {"a": "x", "speed": 4.5}
    path.write_text(json.dumps(text))
    with pytest.raises(InputError, match=r"toy\.json.*'model'.*toy-model"):
        read_model_file(path)


@pytest.mark.parametrize("kind", ["speed-canonical-pem", "direct", "greybox", "canonical-pem",
                                  "experiment-model"])  # fmt: skip
def test_model_over_speed_saves_its_critical_speeds(kind, models, tmp_path):
    """A model over speed saves v_d, v_w, v_c: equal, bit for bit, to the model's own
    ``critical_speeds()`` (sim.linear) recomputed after loading; a fixed-speed model and the
    experiment model save none.  A file without the field (written before it existed) reads
    back with ``critical_speeds`` None and the same model."""
    model = models[kind]
    path = save_model(model, tmp_path / "m.json")
    saved = read_model_file(path)
    if kind in ("canonical-pem", "experiment-model"):
        assert saved.critical_speeds is None
        assert "critical_speeds" not in json.loads(path.read_text())
        return
    again = saved.model.critical_speeds()
    for name in ("v_d", "v_w", "v_c", "weave_frequency"):
        assert saved.critical_speeds[name] == again[name], name
    assert saved.critical_speeds["vmax"] == 30.0
    assert saved.critical_speeds["intervals"] is None and saved.critical_speeds["note"] is None
    old = json.loads(path.read_text())
    del old["critical_speeds"]
    older = model_from_text(json.dumps(old))
    assert older.critical_speeds is None
    _same(older.model, saved.model)


def test_critical_speed_intervals_and_note_saved_verbatim(models, tmp_path):
    """The caller's intervals and note come back as given; a fixed-speed model refuses them
    (it has no critical speeds), and a hand-edited fixed-speed file carrying them is refused."""
    iv = {"level": 0.95, "method": "profile",
          "v_w": {"value": 4.29, "std": 0.01, "interval": [4.27, 4.31], "open": False}}  # fmt: skip
    path = save_model(models["speed-canonical-pem"], tmp_path / "s.json",
                      critical_speed_intervals=iv, critical_speeds_note="why not")  # fmt: skip
    crit = read_model_file(path).critical_speeds
    assert crit["intervals"] == iv and crit["note"] == "why not"
    with pytest.raises(ValueError, match="fixed-speed CanonicalModel has no critical speeds"):
        save_model(models["canonical-pem"], tmp_path / "c.json", critical_speeds_note="x")
    doc = json.loads(model_json(models["canonical-pem"]))
    doc["critical_speeds"] = json.loads(path.read_text())["critical_speeds"]
    with pytest.raises(InputError, match="'critical_speeds' is given for a fixed-speed"):
        model_from_text(json.dumps(doc))


def test_kalman_gain_models_of_every_layout_load(runs, tmp_path):
    """A Kalman-gain fit saves its noise parameters (eta: 5 process-noise entries and 3 sensor
    ratios for four outputs, 4 references, 4 sensor variances = 16 values) and loads bit for
    bit; files of the earlier layouts (3 + 2 + 4 and 5 + 4 + 4 values) load with the same K
    (K is saved itself) and any other length is refused naming the field."""
    m = pem.fit(runs[1], multistart=False, noise_model="kalman")
    assert m.gain_noise.shape == (16,)
    back = load_model(save_model(m, tmp_path / "k.json"))
    _same(_without_structure(m), back)
    text = model_json(m)
    for n in (9, 13):
        obj = json.loads(text)
        obj["model"]["gain_noise"] = obj["model"]["gain_noise"][:n]
        old = model_from_text(json.dumps(obj)).model
        assert old.gain_noise.shape == (n,) and np.array_equal(old.K, m.K)
    obj = json.loads(text)
    obj["model"]["gain_noise"] = obj["model"]["gain_noise"][:11]
    with pytest.raises(InputError, match="gain_noise"):
        model_from_text(json.dumps(obj))
