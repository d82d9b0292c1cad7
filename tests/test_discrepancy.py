"""Injected-effect trials: the pipeline, not told, names the effect (linear experiment
model as the simulator, 10 substeps, noise + encoder quantization)."""

from __future__ import annotations

import pytest

from ident.discrepancy import evaluate, identify, synthetic_windows, whiteness
from ident.experiment_model import ExperimentModel


def test_whiteness_band():
    """White noise: about 1 % of r(1..25) outside the 99 % band (identification.md T10)."""
    import numpy as np

    e = np.random.default_rng(0).normal(size=20000)
    assert whiteness(e)["fraction_outside"] <= 0.12


@pytest.mark.slow
@pytest.mark.parametrize(
    "effect, value",
    [("steer_viscous_damping", 0.4), ("command_gain", 0.8), ("input_delay", 0.03)],
)
def test_injected_library_effect_is_named(effect, value):
    """Right effect ranked first, magnitude within 20 % (brief), held-out error halves."""
    truth = ExperimentModel(effects={effect: value})
    fit = synthetic_windows(truth, [1.5, 3.5], 4, seed=1)
    held = synthetic_windows(truth, [2.5, 4.5], 4, seed=2)
    res = identify(ExperimentModel(), fit, max_effects=2)
    assert res.verdict[0] == effect
    assert res.effects[0].value == pytest.approx(value, rel=0.2)
    ev = evaluate(ExperimentModel(), res.model, held)
    assert ev["summary"]["error_after"] <= 0.5 * ev["summary"]["error_before"]


@pytest.mark.slow
def test_effect_outside_library_is_unexplained():
    """Roll viscous damping is not in the library: the verdict must start 'unexplained'."""
    truth = ExperimentModel(effects={"roll_viscous_damping": 1.5})
    res = identify(ExperimentModel(), synthetic_windows(truth, [1.5, 3.5], 4, seed=3),
                   max_effects=2)  # fmt: skip
    assert res.verdict[0] == "unexplained"
