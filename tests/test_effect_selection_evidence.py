"""Evidence of the effect selection: noise floors under coloured noise, the evidence record
and its printed lines, and the verdicts on blind-generator logs whose answer is known."""

import numpy as np
import pytest

from bikeid.ident.effect_fit import noise_floor, residual_noise_floor
from bikeid.ident.effect_selection import evidence_lines

T = np.arange(100) * 0.01
DECAY = 0.5 * np.exp(-T) * np.sin(2 * np.pi * 1.5 * T)  # a weave-like decay [rad/s]


def _ar1(rng: np.random.Generator, a: float, std: float, n: int = 100) -> np.ndarray:
    e, x = np.empty(n), rng.normal(0.0, std)
    for k in range(n):
        x = a * x + rng.normal(0.0, std * np.sqrt(1 - a * a))
        e[k] = x
    return e


@pytest.mark.parametrize("a", [0.0, 0.7])
def test_residual_floor_recovers_coloured_noise(a):
    """The residual floor is the noise variance whatever its colour; the second-difference
    floor is right for white noise and, analytically, (1 - a)(3 - a) / 3 = 0.23 of it for
    AR(1) with a = 0.7 (why the old 'unexplained' verdict failed on coloured noise).
    40 windows of 100 samples: the relative standard error of a variance estimate from
    ~4000 samples with correlation 0.7 is ~ sqrt(2 (1 + a^2) / (1 - a^2) / 4000) ~ 0.04, so
    15 % is about 4 standard errors; the residual carries a smooth model error of 3 % of the
    decay (what a good model leaves)."""
    rng = np.random.default_rng(1)
    std = 0.01
    res = np.concatenate([0.03 * DECAY + _ar1(rng, a, std) for _ in range(40)])
    got = residual_noise_floor(res, [100] * 40) / (res.size * std**2)
    assert got == pytest.approx(1.0, abs=0.15)
    # the second-difference estimate on the same noise, for contrast (analytic ratio)
    sd = np.mean(
        [np.mean(np.diff(res[i : i + 100], 2) ** 2) / 6 for i in range(0, res.size, 100)]
    )
    assert sd / std**2 == pytest.approx((1 - a) * (3 - a) / 3, abs=0.15)


def test_noise_floor_rejects_unknown_method():
    """A misspelt method is an error, not a silent default."""
    with pytest.raises(ValueError, match="noise-floor method"):
        noise_floor([], "colored")


def test_evidence_lines_state_the_numbers():
    """The printed evidence carries the numbers of the record (held-out ratio, windows
    improved, floors, the rule's statistic and the answer)."""
    ev = {
        "min_heldout_gain": 0.02,
        "effects": {"steer_viscous_damping": {
            "round": 1, "fit_gain": 0.65, "heldout_cost_ratio": 0.483, "heldout_gain": 0.517,
            "heldout_windows_improved": 6, "heldout_windows": 6, "t_joint": 21.4}},
        "unexplained": {
            "rule": "residual", "threshold": 2.0, "unexplained": False, "cost_nominal": 9.3,
            "cost_final": 1.3, "floor_second_difference": 0.05, "floor_coloured": 0.17,
            "floor_residual": 0.9, "explained": 0.86, "explained_coloured": 0.87,
            "final_over_residual_floor": 1.44},
    }  # fmt: skip
    lines = evidence_lines(ev)
    assert "held-out cost ratio 0.483" in lines[0] and "6/6" in lines[0]
    assert "1.44" in lines[1] and lines[1].endswith("-> explained")
