"""When the effect selection accepts an effect: one value, :class:`AcceptanceRule`.

Every threshold of :func:`bikeid.ident.effects.selection.select_effects` is a field of
:class:`AcceptanceRule`, with its default stated once here and the data it was tuned on named
beside it (and the pipeline's other defaults, the plant test's level, the weave floor and the
decay detector's, in :data:`PIPELINE_DEFAULTS`); ``bikeid measured fit`` and ``measured trials``
build the rule from their options (their help text reads the defaults from it), and the
trial studies pass it on unchanged.

The significance test
---------------------
An effect's estimate ``v`` with window-clustered standard error ``s``
(:func:`bikeid.ident.effects.fit.effect_std`) gives ``t = |v - absent| / s`` (for a parameter
correction along a calibrated direction, its reach beyond the uncertainty band over ``s``).
With G clusters (decay windows, plus one for the weave term) the sandwich estimate has about
G - 1 degrees of freedom, so ``t`` is referred to Student's t with G - 1 degrees of freedom
(the small-cluster correction of Cameron, Gelbach & Miller 2008 / Bell & McCaffrey 2002; with
fewer than p + 2 clusters the fit falls back to N_eff - p, see
:func:`bikeid.ident.effects.fit.effect_dof`) and its two-sided p-value is computed.

Multiple comparisons: each round of the forward selection tests every remaining candidate,
so a selection of R rounds over K candidates makes at most m = K + (K - 1) + ... +
(K - R + 1) tests.  An effect is significant when its p-value is at most ``alpha / m``
(Bonferroni over candidates x rounds), which bounds the family-wise error rate, the
probability that any absent effect passes its test, by ``alpha`` whatever the dependence of
the tests.  The held-out checks and the pruning after the joint fit only remove effects, so
they keep that bound.  ``correction="none"`` tests each effect at ``alpha`` alone (no
family-wise statement).  The p-values assume the fitted model's residual errors, clustered by
window, are the only noise; when the nominal calibration holds an offset on its box's edge
they are conditional on that offset (:class:`bikeid.ident.effects.selection.Identification`
says so).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from scipy import stats

from bikeid.ident.effects.nominal_uncertainty import DEFAULT_TEXT, NominalUncertainty

__all__ = [
    "AcceptanceRule",
    "EXPLAINED_MIN",
    "EXPLAINED_MIN_CALIBRATED",
    "EXPLAINED_TO_NAME",
    "LINEAR_PLANT_MARGIN",
    "PIPELINE_DEFAULTS",
    "RESIDUAL_MAX",
    "INSTRUMENT_MAX",
    "WEAVE_EPS",
    "UNEXPLAINED_RULES",
    "CORRECTIONS",
    "paired_p_value",
    "t_p_value",
]

#: The ``floor`` rule's threshold with the stated bicycle taken as exact (explained fraction
#: of the nominal cost above the second-difference noise floor); set on the first blind
#: trials (docs/measured.md, "Blind trials").
EXPLAINED_MIN = 0.9
#: The ``floor`` rule's default threshold when the nominal is calibrated within its
#: uncertainty.  Chosen on the blind trials (seed 3: 48 library, 72 outside-library logs,
#: rescored exactly from the log): 0.85 names the right effect first in 26 of 48 against 21
#: at 0.9, with 0 of 72 outside effects misattributed at both (0.8: 28 and 1 of 72); seed 2
#: is unchanged by it (15 of 24, 0 of 12); seed 4, out of sample: 30 of 48 and 1 of 72
#: against 29 and 0 (docs/measured.md, "The nominal within its uncertainty").
EXPLAINED_MIN_CALIBRATED = 0.85
#: Least explained fraction (as for ``floor``) for an ``unexplained`` verdict to name its
#: accepted effects: below it they are the library's nearest members to a residual no member
#: explains well, reported in the evidence (``nearest``) and not named.  Chosen on the
#: closure logs of the independent linear truth (seeds 16-23, development data): the
#: injected library effects left 0.80-1.00 explained, the nearest members accepted for roll
#: damping (outside the library) 0.18-0.20.
EXPLAINED_TO_NAME = 0.5
#: The ``residual`` rule's threshold: final cost over the noise part of the final residual
#: (white noise and the right model give about 1).
RESIDUAL_MAX = 2.0
#: The ``instruments`` rule's threshold: ``unexplained`` when the final cost exceeds this
#: multiple of the instruments' floor
#: (:func:`~bikeid.ident.effects.instrument_floor.instrument_floor`).  Set on the closure
#: benchmark's seed-0 logs (building seed), nominal
#: model: no-effect logs gave cost / floor 0.95 (CSV without the law, k-step error) and 1.00
#: (with the law, loop), an outside-library roll damping 2.15 and 1.84.
INSTRUMENT_MAX = 1.3
UNEXPLAINED_RULES = ("instruments", "floor", "coloured", "residual")
CORRECTIONS = ("bonferroni", "none")
#: Floor of the weave error in the selection score (the weave-eigenvalue fit scatter, ~2 %).
WEAVE_EPS = 0.02
#: Least factor by which the linear nominal plant's cost must undercut the nonlinear one's
#: before the blind trials' ``nonlinear="auto"``
#: (:func:`bikeid.experiments.measured.blind_trials.run_blind_trial`) fits from the linear
#: plant (:func:`bikeid.ident.effects.selection.choose_nominal_plant`, a choice before any
#: effect; ``bikeid measured fit --plant auto`` chooses after selection instead,
#: :func:`bikeid.ident.effects.selection.choose_plant`).  Calibrated on the
#: blind trials' nominal costs (``benchmarks/bench_blind_trials.py --n 180 --seed 0|1
#: --nominal-only``, 360 trials): the ratio nonlinear / linear reached at most 1.14 on the
#: 89 trials from bikeid's nonlinear plant, while 23 of the 31 no-effect trials from the
#: independent linear plant exceed 1.2 (5 of them are within 5 % of 1: no margin separates
#: those); the real steer-by-wire decays give 0.80-1.03 for every speed split (1.10 for
#: 4.5 m/s alone).  1.2 is the round factor above all of these nonlinear cases
#: (docs/measured.md, "Blind trials").
LINEAR_PLANT_MARGIN = 1.2

#: The pipeline's defaults in one place (``bikeid measured fit`` without options), each with
#: where it lives and the data it was chosen on.  "Development data" is every speed split of
#: the four shared steer-by-wire speeds: none of them is out of sample for these defaults.
#: tests/experiments/measured/test_closure_rates.py checks each value against the live
#: constant or option.
PIPELINE_DEFAULTS: dict[str, dict] = {
    "alpha": {"value": 0.05, "where": "AcceptanceRule.alpha (--alpha)",
              "tuned_on": "not tuned: the conventional family-wise level"},
    "correction": {"value": "bonferroni", "where": "AcceptanceRule.correction (--correction)",
                   "tuned_on": "not tuned (candidates x rounds); false positives measured on 40 "
                   "no-effect blind logs of a fresh seed"},
    "min_gain": {"value": 0.02, "where": "AcceptanceRule.min_gain",
                 "tuned_on": "the weave-eigenvalue fit scatter (~2 %) of the real decays "
                 "(development data)"},
    "min_heldout_gain": {"value": None, "where": "AcceptanceRule.min_heldout_gain",
                         "tuned_on": "= min_gain; the strict 0.25 on the blind trials"},
    "min_improved": {"value": 0.0, "where": "AcceptanceRule.min_improved",
                     "tuned_on": "not used by default (strict 0.75: blind trials)"},
    "unexplained_rule": {"value": "floor", "where": "AcceptanceRule.unexplained_rule",
                         "tuned_on": "first blind trials"},
    "INSTRUMENT_MAX": {"value": INSTRUMENT_MAX, "where": "acceptance.INSTRUMENT_MAX",
                       "tuned_on": "closure benchmark seed 0 (no effect, roll damping)"},
    "EXPLAINED_MIN_CALIBRATED": {"value": 0.85, "where": "acceptance.EXPLAINED_MIN_CALIBRATED",
                                 "tuned_on": "blind seed 3 (seed 4 out of sample)"},
    "EXPLAINED_MIN": {"value": 0.9, "where": "acceptance.EXPLAINED_MIN",
                      "tuned_on": "first blind trials (the bicycle taken as exact)"},
    "EXPLAINED_TO_NAME": {"value": 0.5, "where": "acceptance.EXPLAINED_TO_NAME",
                          "tuned_on": "closure logs, linear truth, seeds 16-23 (development "
                          "data): library effects 0.80-1.00 explained, nearest members of "
                          "roll damping 0.18-0.20"},
    "RESIDUAL_MAX": {"value": 2.0, "where": "acceptance.RESIDUAL_MAX",
                     "tuned_on": "not tuned: white noise and the right model give ~1"},
    "nominal_uncertainty": {"value": DEFAULT_TEXT,
                            "where": "nominal_uncertainty.DEFAULT_TEXT (--nominal-uncertainty)",
                            "tuned_on": "blind seeds 2-4"},
    "plant_alpha": {"value": 0.05, "where": "AcceptanceRule.alpha (--alpha; the level of "
                    "selection.choose_plant's paired test of the two plants' final models)",
                    "tuned_on": "not tuned: the rule's level, one two-sided test; rates "
                    "measured on closure seeds 0-7 (benchmarks/bench_closure_rates.py)"},
    "LINEAR_PLANT_MARGIN": {"value": 1.2, "where": "acceptance.LINEAR_PLANT_MARGIN",
                            "tuned_on": "blind seeds 0 and 1, nominal costs only (360 trials); "
                            "real decays of every speed split (development data); used only "
                            "by the blind trials' plant choice before selection, not by "
                            "measured fit"},
    "WEAVE_EPS": {"value": 0.02, "where": "acceptance.WEAVE_EPS",
                  "tuned_on": "the weave-eigenvalue fit scatter of the real decays "
                  "(development data)"},
    "weave_weight": {"value": "auto", "where": "measured fit --weave-weight",
                     "tuned_on": "real decays, every speed split (development data)"},
    "plant": {"value": "auto", "where": "measured fit --plant",
              "tuned_on": "not tuned: both plants' selections, chosen by plant_alpha"},
    "max_effects": {"value": 3, "where": "measured fit --max-effects",
                    "tuned_on": "real decays (development data)"},
    "decays": {"value": "listed", "where": "measured fit --decays",
               "tuned_on": "the source's curated segments.csv of the real logs"},
    "DECAY_K": {"value": 6.0, "where": "dataset.decays.DECAY_K",
                "tuned_on": "the four eigen_normal logs (development data)"},
    "DECAY_MIN_PEAK": {"value": 0.2, "where": "dataset.decays.DECAY_MIN_PEAK",
                       "tuned_on": "the four eigen_normal logs (development data)"},
    "DECAY_MAX_LENGTH": {"value": 3.0, "where": "dataset.decays.DECAY_MAX_LENGTH",
                         "tuned_on": "closure delay logs, linear truth, seeds 0-7 (3 and 4 s "
                         "keep the same decays; development data)"},
    "DECAY_SETTLE": {"value": 0.5, "where": "dataset.decays.DECAY_SETTLE",
                     "tuned_on": "closure logs, linear truth, seeds 1-3 (half-sine pushes of "
                     "0.12-0.29 s: the roll-rate extreme 0-0.07 s before the push ends; "
                     "development data)"},
    "DECAY_RESPONSE_MAX": {"value": 1.5, "where": "dataset.decays.DECAY_RESPONSE_MAX",
                           "tuned_on": "closure logs, linear truth, input-delay seeds 32 and 38 "
                           "(held-out seeds, looked at after their rates were measured: "
                           "response lobes 1.1-1.36 x the push's)"},
    "DECAY_MAX_SETTLE": {"value": 0.2, "where": "dataset.decays.DECAY_MAX_SETTLE",
                         "tuned_on": "not tuned: the longest half-sine push of the generator "
                         "(0.4 s) rises for about 0.3 s"},
}


def t_p_value(t: float, dof: float) -> float:
    """Two-sided p-value of a t statistic against Student's t with ``dof`` degrees of freedom.

    Parameters
    ----------
    t : float
        The statistic (dimensionless; its sign is ignored; inf gives 0).
    dof : float
        Degrees of freedom (> 0; inf: the normal distribution).

    Returns
    -------
    float
        P(|T| >= |t|) in [0, 1]; 1 when ``t`` is not a number.
    """
    t = abs(float(t))
    if math.isnan(t):
        return 1.0
    if math.isinf(t):
        return 0.0
    if not dof > 0:
        return 1.0
    return float(2.0 * (stats.norm.sf(t) if math.isinf(dof) else stats.t.sf(t, dof)))


def paired_p_value(d) -> float:
    """Two-sided p-value of a paired t test that the mean of the differences ``d`` is zero.

    Used to tell two candidate effects apart by their held-out decays: ``d`` holds, per
    held-out decay, one candidate's cost minus the other's; t = mean / (sd / sqrt(n)) is
    referred to Student's t with n - 1 degrees of freedom (the decays are independent pushes).

    Parameters
    ----------
    d : array_like
        Paired differences (any unit; at least 2).

    Returns
    -------
    float
        The p-value in [0, 1]; 1 with fewer than 2 differences or all of them zero, 0 when
        they are all equal and not zero.
    """
    import numpy as np

    d = np.asarray(d, dtype=float)
    if d.size < 2 or not np.any(d):
        return 1.0
    sd = float(np.std(d, ddof=1))
    if sd == 0.0:
        return 0.0
    return t_p_value(float(np.mean(d)) / (sd / math.sqrt(d.size)), d.size - 1)


@dataclass(frozen=True)
class AcceptanceRule:
    """The acceptance settings of the effect selection (module docstring), one value.

    Attributes
    ----------
    alpha : float
        Family-wise level of the significance tests (default 0.05): the probability, under
        the test's assumptions, that any absent effect passes its test.
    correction : str
        ``"bonferroni"`` (default): each test at ``alpha / m``, m the candidate tests of all
        rounds; ``"none"``: each test at ``alpha``.
    min_gain : float
        Least fractional reduction of the fit-half cost (weave term included) an effect
        must bring (default 0.02: the weave-eigenvalue fit scatter, about 2 %).
    min_heldout_gain : float or None
        Least fractional reduction of the held-out cost, in [0, 1); None (default): equal
        to ``min_gain``.  The blind trials' strict setting is 0.25 (docs/measured.md,
        "Blind trials").
    min_improved : float
        Least share of the held-out decays whose own cost the effect must lower, in
        [0, 1] (a paired sign criterion; default 0: only the summed held-out cost; the
        strict setting is 0.75).
    unexplained_rule : str
        How ``"unexplained"`` is decided (:data:`UNEXPLAINED_RULES`): ``"floor"`` (default),
        ``"instruments"`` (final cost over the instruments' floor above
        :data:`INSTRUMENT_MAX`; no effect and no structure left: nothing is said; not the
        default: on the closure's seed-18 roll-damping logs it let a steer inertia be named
        where ``floor`` says ``unexplained``), ``"coloured"`` or ``"residual"``
        (:func:`bikeid.ident.effects.selection.select_effects`).
    unexplained_threshold : float or None
        That rule's threshold (> 0); None (default): :data:`INSTRUMENT_MAX` for
        ``"instruments"``, :data:`RESIDUAL_MAX` for ``"residual"``, else
        :data:`EXPLAINED_MIN_CALIBRATED` with a nominal uncertainty and
        :data:`EXPLAINED_MIN` without.
    nominal_uncertainty : NominalUncertainty or None
        The stated bicycle's uncertainty (default: :class:`NominalUncertainty`'s default,
        inertias +-5 %, trail +-2 mm, instrument offsets; tuned on blind seeds 2-4,
        docs/measured.md "The nominal within its uncertainty"): the nominal is calibrated
        within it before any effect is tried and a parameter correction is tested beyond
        it; None takes the stated bicycle as exact.

    Raises
    ------
    ValueError
        Naming the field and its allowed range, if a value is outside it.
    """

    alpha: float = 0.05
    correction: str = "bonferroni"
    min_gain: float = 0.02
    min_heldout_gain: float | None = None
    min_improved: float = 0.0
    unexplained_rule: str = "floor"
    unexplained_threshold: float | None = None
    nominal_uncertainty: NominalUncertainty | None = field(default_factory=NominalUncertainty)

    def __post_init__(self) -> None:
        if not (isinstance(self.alpha, (int, float)) and 0.0 < self.alpha < 1.0):
            raise ValueError(f"alpha must be in (0, 1) (a family-wise level), got {self.alpha!r}")
        if self.correction not in CORRECTIONS:
            raise ValueError(f"unknown correction {self.correction!r}; use "
                             f"{' or '.join(map(repr, CORRECTIONS))}")  # fmt: skip
        if not (math.isfinite(self.min_gain) and 0.0 <= self.min_gain < 1.0):
            raise ValueError(f"min_gain must be in [0, 1) (a fraction of the fit cost), got "
                             f"{self.min_gain!r}")  # fmt: skip
        if self.unexplained_rule not in UNEXPLAINED_RULES:
            raise ValueError(f"unknown unexplained_rule {self.unexplained_rule!r}; use "
                             "'instruments', 'floor', 'coloured' or 'residual'")  # fmt: skip
        g = self.min_heldout_gain
        if g is not None and not 0.0 <= g < 1.0:
            raise ValueError(f"min_heldout_gain must be in [0, 1) (a fraction of the held-out "
                             f"cost), got {g!r}")  # fmt: skip
        if not 0.0 <= self.min_improved <= 1.0:
            raise ValueError(f"min_improved must be in [0, 1] (a share of the held-out decays), "
                             f"got {self.min_improved!r}")  # fmt: skip
        x = self.unexplained_threshold
        if x is not None and not (math.isfinite(x) and x > 0):
            raise ValueError(f"unexplained_threshold must be a finite number > 0, got {x!r}")

    @classmethod
    def exact(cls, **kw) -> AcceptanceRule:
        """The rule with the stated bicycle taken as exact (no nominal calibration).

        Parameters
        ----------
        **kw
            Other fields.

        Returns
        -------
        AcceptanceRule
            ``nominal_uncertainty=None``, the other fields their defaults or ``kw``.
        """
        return cls(nominal_uncertainty=None, **kw)

    @property
    def heldout_gain(self) -> float:
        """The held-out gain asked of an effect: ``min_heldout_gain``, else ``min_gain``."""
        return self.min_gain if self.min_heldout_gain is None else float(self.min_heldout_gain)

    @property
    def threshold(self) -> float:
        """The ``unexplained`` rule's threshold (the field, else its stated default)."""
        if self.unexplained_threshold is not None:
            return float(self.unexplained_threshold)
        if self.unexplained_rule == "residual":
            return RESIDUAL_MAX
        if self.unexplained_rule == "instruments":
            return INSTRUMENT_MAX
        return EXPLAINED_MIN if self.nominal_uncertainty is None else EXPLAINED_MIN_CALIBRATED

    def level(self, tests: int) -> float:
        """The level each of ``tests`` significance tests is held to.

        Parameters
        ----------
        tests : int
            Number of candidate tests in the family (candidates x rounds, >= 1).

        Returns
        -------
        float
            ``alpha / tests`` (Bonferroni) or ``alpha`` (``correction="none"``).
        """
        return self.alpha / max(int(tests), 1) if self.correction == "bonferroni" else self.alpha

    def adjusted(self, p: float, tests: int) -> float:
        """A p-value adjusted for the family: ``min(1, tests p)`` (Bonferroni) or ``p``.

        Parameters
        ----------
        p : float
            The test's own p-value.
        tests : int
            Number of tests in the family.

        Returns
        -------
        float
            Comparable with ``alpha``.
        """
        return min(1.0, max(int(tests), 1) * p) if self.correction == "bonferroni" else p

    def as_dict(self) -> dict:
        """The rule, JSON-ready (the nominal uncertainty as its half-widths or None).

        Returns
        -------
        dict
            One key per field.
        """
        nu = self.nominal_uncertainty
        return {"alpha": self.alpha, "correction": self.correction, "min_gain": self.min_gain,
                "min_heldout_gain": self.min_heldout_gain, "min_improved": self.min_improved,
                "unexplained_rule": self.unexplained_rule,
                "unexplained_threshold": self.unexplained_threshold,
                "nominal_uncertainty": None if nu is None else nu.as_dict()}  # fmt: skip
