"""The interval functions' default refusals (``ident.trust.check_trust``), each both ways.

Each refusal is the one ``bikeid identify`` makes; here every one is shown to refuse when its
condition holds, to give the intervals (with a note) when opted out of by name, and not to
refuse when its condition does not hold.  The model is the benchmark's linearization at 5 m/s
(Meijaard 2007, ``sim.linear``) with a small covariance, so the intervals exist and only the
gate decides.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bikeid.ident.canonical import theta_from_matrices
from bikeid.ident.pem import CanonicalModel
from bikeid.ident.structure import StructureCheck
from bikeid.ident.trust import (
    AMPLITUDE_LIMIT_DEG,
    NO_STRUCTURE_NOTE,
    REMEDY_KALMAN,
    WithheldIntervals,
)
from bikeid.ident.uncertainty import bode_bands, eigenvalue_intervals
from bikeid.sim import linear
from bikeid.sim.errors import UntrustworthyResult
from bikeid.sim.parameters import benchmark

V = 5.0


def _check(rejected: bool) -> StructureCheck:
    row = {
        "kind": "independence",
        "output": "phi",
        "statistic": 80.0,
        "dof": 25,
        "p_value": 1e-9 if rejected else 0.5,
        "rejected": rejected,
        "advisory": False,
    }
    speeds = (V,) if rejected else ()
    return StructureCheck(level=0.01, per_test_level=0.0025, n_tests=4, tests={V: [row]},
                          rejected_speeds=speeds, withheld_speeds=speeds)  # fmt: skip


@pytest.fixture(scope="module")
def model() -> CanonicalModel:
    theta = theta_from_matrices(linear.canonical_matrices(benchmark()), V)
    return CanonicalModel(
        theta=theta, covariance=np.diag((1e-3 * np.abs(theta)) ** 2), K=np.zeros((4, 4)),
        dt=0.01, speed=V, noise_covariance=np.eye(4), nfev=10, noise_model="kalman",
        structure=_check(False), roll_rms_deg=0.1,
    )  # fmt: skip


def test_a_clean_model_gets_intervals_without_notes(model):
    ei = eigenvalue_intervals(model, method="delta")
    assert ei.notes == ()
    truth = linear.eigenvalues(benchmark(), V)
    assert np.all(ei.contains(truth)[0])


def test_no_structure_check_gives_intervals_with_a_note(model):
    ei = eigenvalue_intervals(dataclasses.replace(model, structure=None), method="delta")
    assert ei.notes == (NO_STRUCTURE_NOTE,)


@pytest.mark.parametrize(
    ("change", "keyword", "remedy"),
    [
        ({"structure": _check(True)}, "refuse_structure", ""),
        ({"roll_rms_deg": 2 * AMPLITUDE_LIMIT_DEG}, "refuse_amplitude", ""),
        ({"noise_model": "none", "unstable_plant": "its start is unstable"},
         "refuse_output_error", REMEDY_KALMAN),
    ],
)  # fmt: skip
def test_each_refusal_both_ways(model, change, keyword, remedy):
    bad = dataclasses.replace(model, **change)
    for func in (lambda m, **kw: eigenvalue_intervals(m, method="delta", **kw),
                 lambda m, **kw: bode_bands(m, [1.0, 10.0], **kw)):  # fmt: skip
        with pytest.raises(WithheldIntervals) as info:
            func(bad)
        assert isinstance(info.value, UntrustworthyResult)
        assert info.value.check == keyword and info.value.remedy == remedy
        assert f"{keyword}=False" in str(info.value)
        out = func(bad, **{keyword: False})  # opted out by name: intervals with a note
        notes = out.notes if hasattr(out, "notes") else out[0].notes
        assert len(notes) == 1 and notes[0] == info.value.reason


def test_amplitude_limit_is_a_strict_bound(model):
    """At the limit itself the intervals are given; just above it, refused."""
    eigenvalue_intervals(dataclasses.replace(model, roll_rms_deg=AMPLITUDE_LIMIT_DEG),
                         method="delta")  # fmt: skip
    with pytest.raises(WithheldIntervals):
        eigenvalue_intervals(dataclasses.replace(model, roll_rms_deg=AMPLITUDE_LIMIT_DEG * 1.01),
                             method="delta")  # fmt: skip


@pytest.mark.parametrize(("radius", "refused"), [(1 - 1e-9, True), (1 - 1e-3, False)])
def test_boundary_refusal_both_ways(model, radius, refused):
    """A free-gain fit (``noise_model="gain"``) with K chosen so that Ad - K C =
    diag(radius, 0.5, 0.5, 0.5) (all four states measured: C = I in the canonical order) is
    refused above 1 - PREDICTOR_BOUNDARY_TOL and not below."""
    Ad, _, C, _ = model.predictor()
    assert np.array_equal(C, np.eye(4))
    K = Ad - np.diag([radius, 0.5, 0.5, 0.5])
    gain = dataclasses.replace(model, noise_model="gain", K=K)
    if not refused:
        ei = eigenvalue_intervals(gain, method="delta")
        assert ei.predictor_radius == pytest.approx(radius, abs=1e-12)
        return
    with pytest.raises(WithheldIntervals, match="stability boundary") as info:
        eigenvalue_intervals(gain, method="delta")
    assert info.value.remedy == REMEDY_KALMAN
    assert eigenvalue_intervals(gain, method="delta", refuse_boundary=False).notes
