"""The model API rules, checked on every public linear model class (ident.linear_model).

Every model class of the method table (``ident.methods.METHODS``) is walked; each must:

- derive from ``LinearModel`` (and, if defined over speed, ``SpeedDependentModel``) without
  redefining ``state_space`` / ``eigenvalues`` / ``eigenvalues_vs_speed`` /
  ``critical_speeds``, so the one signature holds: ``state_space(speed=None, dt=None, *,
  inputs=None, order="bikeid")``, ``eigenvalues(speed=None)``;
- give a StateSpace whose states are bikeid's [phi, delta, phidot, deltadot] and whose
  outputs are in the same order (Chen & Dao's order only with ``order="chen_dao"``), equal
  to ``sim.linear.state_space`` of the same bicycle (an independent construction);
- return eigenvalues sorted by real then imaginary part (numpy.sort_complex), each named
  as ``sim.linear.eigenvalues_vs_speed``'s branch tracking names it (the weave branches'
  real roots below v_d as ``weave (real)``), all four named at any speed of the benchmark,
  and ``eigenvalue_intervals`` in the same order with the same names;
- keep stored numbers as attributes (``params``, ``stderr`` are not callables).

Every model here is built from the benchmark bicycle's exact matrices (Meijaard 2007), so
the expected values are the benchmark's own; tolerances are round-off of the algebra.
"""

from __future__ import annotations

import inspect

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.ident.canonical import speed_params_from_matrices, theta_from_matrices
from bikeid.ident.direct import DirectResult
from bikeid.ident.greybox import GreyboxModel
from bikeid.ident.linear_model import (
    WEAVE_REAL,
    Eigenvalues,
    LinearModel,
    SpeedDependentModel,
    mode_names,
)
from bikeid.ident.methods import METHODS
from bikeid.ident.pem import CanonicalModel, SpeedCanonicalModel
from bikeid.ident.uncertainty import eigenvalue_intervals
from bikeid.sim.conventions import CANONICAL_STATE, LINEAR_STATE
from bikeid.sim.errors import InputError
from bikeid.sim.linear import canonical_matrices, eigenvalues_vs_speed, state_space
from bikeid.sim.parameters import benchmark

P = benchmark()
CM = canonical_matrices(P)
V = 5.0  # between v_w = 4.29 and v_c = 6.02: weave complex, capsize and caster real
ALL_OUTPUTS = ("phi", "phidot", "delta", "deltadot")  # pem's default, Chen & Dao's order


def _matrices() -> dict:
    return {"M": CM.M, "C1": CM.C1, "K0": CM.K0, "K2": CM.K2, "g": CM.g, "H": np.zeros(2)}


def _canonical(v: float = V) -> CanonicalModel:
    return CanonicalModel(theta=theta_from_matrices(CM, v), covariance=1e-6 * np.eye(10),
                          K=np.zeros((4, 4)), dt=0.01, speed=v, noise_covariance=np.eye(4),
                          outputs=ALL_OUTPUTS)  # fmt: skip


def _speed_canonical() -> SpeedCanonicalModel:
    return SpeedCanonicalModel(params=speed_params_from_matrices(CM),
                               covariance=1e-6 * np.eye(14), per_speed={V: _canonical()},
                               dt=0.01, g=CM.g, outputs=ALL_OUTPUTS)  # fmt: skip


def _direct() -> DirectResult:
    return DirectResult(**_matrices(), free={}, stderr={}, covariance={}, condition={},
                        vaf_moore={}, vaf_variance={}, n_samples=0, method="ls")  # fmt: skip


def _greybox() -> GreyboxModel:
    return GreyboxModel(**_matrices(), free={}, stderr={}, covariance=np.zeros((0, 0)),
                        condition=1.0, inflation={}, weakest={}, dropped=(), fixed={},
                        symmetric=True, K={V: np.zeros((4, 4))}, dt=0.01,
                        outputs=ALL_OUTPUTS, speeds=(V,),
                        noise_covariance=np.eye(4))  # fmt: skip


BUILDERS = {CanonicalModel: _canonical, SpeedCanonicalModel: _speed_canonical,
            DirectResult: _direct, GreyboxModel: _greybox}  # fmt: skip
MODEL_CLASSES = tuple(dict.fromkeys(c for m in METHODS.values() for c in m.model_classes))


def _speed(model) -> float | None:
    return V if isinstance(model, SpeedDependentModel) else None


def test_every_model_class_of_the_table_is_walked():
    """The walk below covers every class the method table names (a new method's class
    must get a builder here, so the rules are checked for it)."""
    assert set(MODEL_CLASSES) == set(BUILDERS), set(MODEL_CLASSES) ^ set(BUILDERS)


@pytest.mark.parametrize("cls", MODEL_CLASSES, ids=lambda c: c.__name__)
def test_one_base_one_signature(cls):
    assert issubclass(cls, LinearModel)
    speed_dependent = cls not in (CanonicalModel,)
    assert issubclass(cls, SpeedDependentModel) == speed_dependent
    names = ["state_space", "eigenvalues"] + (
        ["eigenvalues_vs_speed", "critical_speeds"] if speed_dependent else []
    )
    for name in names:  # inherited, never redefined: one signature for all
        assert getattr(cls, name) is getattr(
            SpeedDependentModel if speed_dependent else LinearModel, name
        ), (cls.__name__, name)
    sig = inspect.signature(cls.state_space)
    assert list(sig.parameters) == ["self", "speed", "dt", "inputs", "order"]
    assert sig.parameters["speed"].default is None and sig.parameters["dt"].default is None
    assert list(inspect.signature(cls.eigenvalues).parameters) == ["self", "speed"]


@pytest.mark.parametrize("cls", MODEL_CLASSES, ids=lambda c: c.__name__)
def test_state_space_named_in_bikeid_order_and_equal_to_sim_linear(cls):
    """States and outputs [phi, delta, phidot, deltadot]; A and the T_delta column equal
    sim.linear.state_space's (round-off: the canonical classes go through M^-1 and a
    permutation, 1e-9 relative to the largest entry)."""
    model = BUILDERS[cls]()
    sys = model.state_space(_speed(model), inputs=("T_delta",))
    assert list(sys.state_labels) == list(LINEAR_STATE)
    assert list(sys.output_labels) == list(LINEAR_STATE)  # outputs in the states' order
    assert list(sys.input_labels) == ["T_delta"]
    ref = state_space(P, V, inputs=("T_delta",))
    scale = np.abs(ref.A).max()
    np.testing.assert_allclose(sys.A, ref.A, atol=1e-9 * scale)
    np.testing.assert_allclose(sys.B, ref.B, atol=1e-9 * np.abs(ref.B).max())
    np.testing.assert_array_equal(sys.C, np.eye(4))
    cd = model.state_space(_speed(model), inputs=("T_delta",), order="chen_dao")
    assert list(cd.state_labels) == list(CANONICAL_STATE)
    assert list(cd.output_labels) == list(CANONICAL_STATE)
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(cd.A)),
                               np.sort_complex(np.linalg.eigvals(sys.A)), atol=1e-9 * scale)


@pytest.mark.parametrize("cls", MODEL_CLASSES, ids=lambda c: c.__name__)
def test_sampled_state_space_is_the_zero_order_hold(cls):
    """dt gives the exact ZOH model: equal to python-control's own c2d (independent code)."""
    import control

    model = BUILDERS[cls]()
    cont = model.state_space(_speed(model), inputs=("T_delta",))
    disc = model.state_space(_speed(model), 0.01, inputs=("T_delta",))
    ref = control.c2d(cont, 0.01, method="zoh")
    assert disc.dt == 0.01 and list(disc.state_labels) == list(LINEAR_STATE)
    np.testing.assert_allclose(disc.A, ref.A, atol=1e-12)
    np.testing.assert_allclose(disc.B, ref.B, atol=1e-12)


@pytest.mark.parametrize("cls", MODEL_CLASSES, ids=lambda c: c.__name__)
def test_eigenvalues_ordered_and_named(cls):
    """Sorted as numpy.sort_complex, values equal to sim.linear's, names equal to the labels
    that sim.linear.eigenvalues_vs_speed's branch tracking gives at that speed."""
    model = BUILDERS[cls]()
    ev = model.eigenvalues(_speed(model))
    assert isinstance(ev, Eigenvalues)
    np.testing.assert_array_equal(np.asarray(ev), np.sort_complex(np.asarray(ev)))
    sweep = eigenvalues_vs_speed(P, [V, 10.0])
    truth = sweep.values[0]
    for lam, mode in zip(ev, ev.modes, strict=True):
        j = int(np.argmin(np.abs(truth - lam)))
        assert abs(truth[j] - lam) < 1e-8 * abs(truth[j])
        assert mode == sweep.labels[j], (lam, mode, sweep.labels)
    assert sorted(ev.modes) == ["capsize", "caster", "weave", "weave"]


@pytest.mark.parametrize("cls", [c for c in MODEL_CLASSES if issubclass(c, SpeedDependentModel)],
                         ids=lambda c: c.__name__)  # fmt: skip
def test_speed_dependent_models_sweep_and_critical_speeds(cls):
    """Meijaard 2007 Table 2: v_w = 4.2924 m/s, v_c = 6.0243 m/s (4 decimals)."""
    model = BUILDERS[cls]()
    cs = model.critical_speeds()
    assert cs["v_w"] == pytest.approx(4.2924, abs=1e-4)
    assert cs["v_c"] == pytest.approx(6.0243, abs=1e-4)
    sweep = model.eigenvalues_vs_speed([3.0, 5.0, 8.0])
    assert sweep.values.shape == (3, 4) and "weave" in sweep.labels


def test_fixed_speed_model_refuses_other_speeds_and_speed_models_need_one():
    with pytest.raises(InputError, match="fitted at 5 m/s"):
        _canonical().eigenvalues(6.0)
    _canonical().eigenvalues(5.0)  # its own speed is fine
    for builder in (_speed_canonical, _direct, _greybox):
        with pytest.raises(InputError, match="defined over speed"):
            builder().state_space()


def _branch(mode: str) -> str:
    """The tracked branch a name lies on (the weave's real roots lie on the weave's)."""
    return "weave" if mode == WEAVE_REAL else mode


def test_four_real_roots_are_named_by_tracking_over_speed():
    """Below the speed where the weave pair turns complex (v_d = 0.68 m/s for the benchmark)
    all four roots are real; a model over speed names them by tracking its own branches, a
    fixed-speed model by their order along the real axis (ident.linear_model.mode_names);
    both give the tracked branches' names, the weave's two real roots as weave (real)."""
    v = 0.5
    ev = _direct().eigenvalues(v)
    assert np.all(np.abs(np.asarray(ev).imag) < 1e-9)
    sweep = eigenvalues_vs_speed(P, [v, 10.0])
    for lam, mode in zip(ev, ev.modes, strict=True):
        assert _branch(mode) == sweep.labels[int(np.argmin(np.abs(sweep.values[0] - lam)))]
    assert ev.modes == ("caster", "capsize", WEAVE_REAL, WEAVE_REAL)
    assert _canonical(v).eigenvalues().modes == ev.modes


@pytest.mark.parametrize("cls", MODEL_CLASSES, ids=lambda c: c.__name__)
def test_every_model_class_names_every_root_below_v_d(cls):
    """At 0.5 m/s (below v_d = 0.684 m/s, Meijaard 2007 Table 2(a)) every class names all
    four real roots, as the tracked branches of the benchmark (sim.linear) name them."""
    v = 0.5
    model = _canonical(v) if cls is CanonicalModel else BUILDERS[cls]()
    ev = model.eigenvalues(v if isinstance(model, SpeedDependentModel) else None)
    sweep = eigenvalues_vs_speed(P, [v, 10.0])
    for lam, mode in zip(ev, ev.modes, strict=True):
        j = int(np.argmin(np.abs(sweep.values[0] - lam)))
        assert abs(sweep.values[0, j] - lam) < 1e-8 * abs(lam)
        assert _branch(mode) == sweep.labels[j], (lam, mode, sweep.labels)
    assert sorted(ev.modes) == ["capsize", "caster", WEAVE_REAL, WEAVE_REAL]


def test_eigenvalue_intervals_share_the_order_and_names():
    for model in (_canonical(), _speed_canonical()):
        ei = eigenvalue_intervals(model, _speed(model), method="delta")
        ev = model.eigenvalues(_speed(model))
        np.testing.assert_allclose(ei.values, np.asarray(ev), atol=1e-9)
        assert ei.modes == ev.modes
        assert [row["mode"] for row in ei.to_json()["eigenvalues"]] == list(ev.modes)


@pytest.mark.parametrize("cls", MODEL_CLASSES, ids=lambda c: c.__name__)
def test_stored_numbers_are_attributes(cls):
    """A number stored with the model is read as an attribute, never called: the parameter
    values and their standard errors alike."""
    model = BUILDERS[cls]()
    for name in ("params", "stderr", "free", "outputs", "dt"):
        if hasattr(model, name):
            value = getattr(model, name)
            assert not inspect.ismethod(value), (cls.__name__, name)
            assert isinstance(value, (dict, np.ndarray, tuple, float)), (cls.__name__, name)
    if cls is CanonicalModel:  # the former params() method: a deprecated call still works
        with pytest.warns(DeprecationWarning, match="attribute now"):
            assert model.params() == model.params


def test_canonical_model_matrices_in_bikeid_order_chen_dao_by_name():
    m = _canonical()
    ref = state_space(P, V, inputs=("T_delta",))
    np.testing.assert_allclose(m.A, ref.A, atol=1e-9 * np.abs(ref.A).max())
    perm = [LINEAR_STATE.index(s) for s in CANONICAL_STATE]
    np.testing.assert_allclose(m.A_chen_dao, m.A[np.ix_(perm, perm)], atol=0)
    assert m.params == dict(zip(m.params, m.theta, strict=True))


@settings(max_examples=25, deadline=None)
@given(v=st.floats(0.0, 12.0))
def test_names_agree_with_the_tracked_branches_at_any_speed(v):
    """Property: at any speed, below v_d too, the single-speed naming rule (no matrices:
    what a fixed-speed model uses) agrees with the branch tracking of sim.linear
    (independent), every root named, weave (real) exactly where the root is real."""
    ev = _direct().eigenvalues(v)
    sweep = eigenvalues_vs_speed(P, [v, 12.0])
    for lam, mode in zip(ev, ev.modes, strict=True):
        assert _branch(mode) == sweep.labels[int(np.argmin(np.abs(sweep.values[0] - lam)))]
        assert (mode == WEAVE_REAL) == (_branch(mode) == "weave" and abs(lam.imag) <= 1e-9)
    assert mode_names(np.asarray(ev)) == ev.modes
