"""Property tests for anyone's estimator: hypothesis strategies and ``assert_consistent``.

Needs the ``testing`` extra (``pip install 'bikeid[testing]'``: hypothesis); hypothesis is
imported when a strategy is first built, never by ``import bikeid``.

Strategies (each a function returning a hypothesis strategy):

- :func:`bicycles`: the benchmark bicycle with trail, steer tilt, front-frame mass and
  rear-body inertia each scaled by 0.8-1.2 (:class:`~bikeid.sim.parameters.BicycleParameters`;
  draws the parameter validation refuses are rejected);
- :func:`speeds`, :func:`controllers`, :func:`dither_levels`, :func:`seeds`;
- :func:`scenarios`: a :class:`~bikeid.experiments.testbed.scenario.Scenario` from those
  (a bicycle by name, a controller, one or more speeds, a dither level).

:func:`assert_consistent` runs the consistency study
(:func:`~bikeid.experiments.testbed.consistency.run_consistency`) and fails with the
verdict's reason unless it is ``consistent with 1/sqrt(N)``; :func:`assert_verdict` checks
any verdict.  A user's property test::

    from hypothesis import given, settings
    from bikeid.testing import assert_consistent, scenarios

    @settings(max_examples=2, deadline=None)
    @given(scenarios(durations=(25, 50, 100), seeds=8))
    def test_my_estimator(scenario):
        assert_consistent("mymodule:myfit", scenario)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

__all__ = [
    "assert_consistent",
    "assert_verdict",
    "bicycles",
    "controllers",
    "dither_levels",
    "scenarios",
    "seeds",
    "speeds",
]


def _st():
    try:
        from hypothesis import strategies
    except ImportError:  # pragma: no cover - the extra is missing
        raise ImportError(
            "bikeid.testing needs hypothesis: pip install 'bikeid[testing]'"
        ) from None
    return strategies


def bicycles(scale: tuple[float, float] = (0.8, 1.2)):
    """Bicycles near the benchmark: trail c, steer tilt lam, front-frame mass mH and
    rear-body inertia IBxx each multiplied by a factor drawn from ``scale``.

    Parameters
    ----------
    scale : tuple of float, optional
        Range of the factors (default 0.8-1.2).

    Returns
    -------
    hypothesis strategy of BicycleParameters
        Named ``"perturbed"``; draws the parameter checks refuse are rejected (``assume``).
    """
    st = _st()
    from hypothesis import assume

    from bikeid.sim.parameters import benchmark

    base = benchmark()

    @st.composite
    def draw(draw_):
        f = draw_(st.lists(st.floats(*scale), min_size=4, max_size=4))
        try:
            return base.replace(
                c=base.c * f[0], lam=base.lam * f[1], mH=base.mH * f[2],
                IBxx=base.IBxx * f[3], name="perturbed",
            )  # fmt: skip
        except ValueError:
            assume(False)

    return draw()


def speeds(low: float = 3.0, high: float = 8.0):
    """Forward speeds [m/s] where the benchmark has a weave pair, capsize and caster.

    Parameters
    ----------
    low, high : float, optional
        Range [m/s] (default 3-8).

    Returns
    -------
    hypothesis strategy of float
        Speeds rounded to 0.1 m/s.
    """
    return _st().floats(low, high).map(lambda v: round(v, 1))


def controllers(names: Sequence[str] = ("pid",)):
    """Controller names (:func:`bikeid.controllers.registry.make`).

    Parameters
    ----------
    names : sequence of str, optional
        The names to draw from (default the roll PID alone).

    Returns
    -------
    hypothesis strategy of str
    """
    return _st().sampled_from(tuple(names))


def dither_levels(low: float = 1.0, high: float = 3.0):
    """Uniform steer-torque dither amplitudes [N m].

    Parameters
    ----------
    low, high : float, optional
        Range [N m] (default 1-3).

    Returns
    -------
    hypothesis strategy of float
        Amplitudes rounded to 0.1 N m.
    """
    return _st().floats(low, high).map(lambda a: round(a, 1))


def seeds(high: int = 999):
    """Seeds from 0 to ``high``.

    Parameters
    ----------
    high : int, optional
        Largest seed (default 999).

    Returns
    -------
    hypothesis strategy of int
    """
    return _st().integers(0, high)


def scenarios(
    *,
    bicycle_names: Sequence[str] = ("benchmark",),
    controller_names: Sequence[str] = ("pid",),
    n_speeds: int = 1,
    durations: Sequence[float] = (25.0, 50.0, 100.0),
    seeds: int = 8,
    speed_range: tuple[float, float] = (3.0, 8.0),
    dither_range: tuple[float, float] = (1.0, 3.0),
    first_seeds: tuple[int, int] = (0, 10_000),
    **fixed: Any,
):
    """Closed-loop scenarios for a consistency property test.

    Parameters
    ----------
    bicycle_names : sequence of str, optional
        Bicycles by name (default the benchmark).
    controller_names : sequence of str, optional
        Controllers (default the roll PID).
    n_speeds : int, optional
        Distinct speeds per scenario, drawn from :func:`speeds` (default 1).
    durations : sequence of float, optional
        Record lengths [s] of every scenario.
    seeds : int, optional
        Seeds per length (the verdict needs >= 8).
    speed_range, dither_range : tuple of float, optional
        Ranges of :func:`speeds` [m/s] and :func:`dither_levels` [N m].
    first_seeds : tuple of int, optional
        Range of the first seed (``(0, 0)``: seeds 0.. every time).
    **fixed
        Other :class:`~bikeid.experiments.testbed.scenario.Scenario` fields, fixed (e.g.
        ``disturbance=0.5``, ``plant="linear"``).

    Returns
    -------
    hypothesis strategy of Scenario
        The drawn bicycle, controller, speeds, dither and first seed; the rest as given or
        at the Scenario defaults (those of ``bikeid coverage``).
    """
    st = _st()
    from bikeid.experiments.testbed.scenario import Scenario

    n_seeds = seeds

    @st.composite
    def draw(draw_):
        vs = draw_(
            st.lists(speeds(*speed_range), min_size=n_speeds, max_size=n_speeds, unique=True)
        )
        return Scenario(
            bicycle=draw_(st.sampled_from(tuple(bicycle_names))),
            controller=draw_(controllers(controller_names)),
            speeds=tuple(sorted(vs)), dither=draw_(dither_levels(*dither_range)),
            durations=tuple(durations), seeds=n_seeds,
            first_seed=draw_(st.integers(*first_seeds)), **fixed,
        )  # fmt: skip

    return draw()


def assert_verdict(
    expected: str | Sequence[str],
    estimator: Any,
    scenario: Any = None,
    **kw: Any,
) -> dict[str, Any]:
    """Run the consistency study of one estimator and check its verdict.

    Parameters
    ----------
    expected : str or sequence of str
        Acceptable verdicts (``"consistent with 1/sqrt(N)"``, ``"biased"``,
        ``"inconclusive"``, ``"refused"``).
    estimator : Estimator, str or callable
        :class:`~bikeid.experiments.testbed.estimator.Estimator` or what it is made from.
    scenario : Scenario, optional
        The scenario (default ``Scenario()``).
    **kw
        Passed to :func:`~bikeid.experiments.testbed.consistency.run_consistency`
        (``level``, ``workers``, ``dask``, ``out``); ``efficiency`` defaults to False.

    Returns
    -------
    dict
        The estimator's figures (``run_consistency(...)["methods"][name]``).

    Raises
    ------
    AssertionError
        With the verdict and its reason, if the verdict is not one of ``expected``.
    """
    from bikeid.experiments.testbed.consistency import run_consistency
    from bikeid.experiments.testbed.estimator import Estimator

    est = estimator if isinstance(estimator, Estimator) else Estimator(estimator)
    kw.setdefault("efficiency", False)
    res = run_consistency([est], scenario, **kw)["methods"][est.name]
    want = (expected,) if isinstance(expected, str) else tuple(expected)
    if res["verdict"] not in want:
        raise AssertionError(
            f"{est.name}: {res['verdict']} (expected {' or '.join(want)}): "
            f"{res['verdict_detail']['reason']}"
        )
    return res


def assert_consistent(
    estimator: Any | Callable[..., Any], scenario: Any = None, **kw: Any
) -> dict[str, Any]:
    """Assert that the consistency study calls ``estimator`` consistent with 1/sqrt(N).

    Parameters
    ----------
    estimator : Estimator, str or callable
        What :class:`~bikeid.experiments.testbed.estimator.Estimator` takes.
    scenario : Scenario, optional
        The scenario (default ``Scenario()``: 3 lengths, 12 seeds at 5 m/s).
    **kw
        As :func:`assert_verdict`.

    Returns
    -------
    dict
        The estimator's figures.

    Raises
    ------
    AssertionError
        With the verdict and its reason (bias detected, slope interval, refusals).
    """
    from bikeid.experiments.testbed.consistency import CONSISTENT

    return assert_verdict(CONSISTENT, estimator, scenario, **kw)
