"""The closed-loop scenario of the testbed studies, as one frozen value, and its runs.

:class:`Scenario` fixes everything a consistency or coverage study simulates: the bicycle,
the plant (``"linear"``: :func:`bikeid.dataset.linear_loop.simulate`, exact zero-order
hold, whose truth is the linear model itself; ``"nonlinear"``:
:func:`bikeid.dataset.closed_loop.simulate_run`, whose truth is the upright linearization),
the controller, the speeds (fitted together), the steer-torque dither, the unlogged process
noise, the sensor noise, the record lengths and the seeds.  Its defaults are those of
``bikeid coverage`` (:data:`bikeid.experiments.testbed.coverage.DEFAULTS`): roll PID at
100 Hz, uniform dither 3 N m held 5 samples, unlogged white steer torque of standard
deviation 0.5 N m, sensor noise 1e-3 rad and 1e-2 rad/s.

:func:`closed_loop_run` is the one builder of a run: the coverage study, the consistency
study and the tests call it.  The run of (speed index k, seed s) uses the random seed
``s * len(speeds) + k``, so the speeds of one seed never share noise and a one-speed
scenario's seed s is random seed s.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from bikeid.sim.errors import InputError

__all__ = ["PLANTS", "Scenario", "closed_loop_run", "true_modes"]

#: Plants a scenario simulates.
PLANTS = ("linear", "nonlinear")


def _floats(name: str, values: Any, low: float) -> tuple[float, ...]:
    vals = (values,) if isinstance(values, (int, float)) else tuple(values)
    try:
        out = tuple(float(v) for v in vals)
    except (TypeError, ValueError):
        raise InputError(f"{name}={values!r}: give numbers") from None
    if not out or any(not (math.isfinite(v) and v > low) for v in out):
        raise InputError(f"{name}={values!r}: give one or more finite numbers > {low:g}")
    if len(set(out)) != len(out):
        raise InputError(f"{name}={values!r}: give each value once")
    return out


@dataclass(frozen=True)
class Scenario:
    """A closed-loop identification scenario (frozen: a study's key and its record).

    Parameters
    ----------
    bicycle : str
        Bicycle parameter set by name (:func:`bikeid.sim.parameters.by_name`; default
        ``"benchmark"``).
    plant : {"linear", "nonlinear"}
        ``"linear"`` (default): the exact zero-order-hold linear loop, truth exact;
        ``"nonlinear"``: the Whipple plant, truth = its upright linearization (every verdict
        then says "against the linearization"; no process noise is modelled there, so
        ``disturbance`` and ``roll_torque`` must be 0).
    controller : str
        Controller name (:func:`bikeid.controllers.registry.make`; default ``"pid"``),
        sampled at 100 Hz.
    speeds : tuple of float
        Forward speeds [m/s] (default (5,)); every seed gives one run per speed and an
        estimator receives them together.
    dither : float
        Uniform steer-torque dither amplitude [N m] (default 3).
    dither_hold : int
        Samples each dither value is held (default 5).
    disturbance : float
        Standard deviation of the unlogged white steer torque [N m] (process noise; default
        0.5).
    roll_torque : float
        Standard deviation of an unlogged white roll torque [N m] (default 0).
    angle_noise, rate_noise : float
        Sensor noise standard deviations [rad], [rad/s] (default 1e-3, 1e-2).
    durations : tuple of float
        Record lengths [s] (default (25, 100, 400)); N = duration / 0.01 s samples.
    seeds : int
        Seeds per duration (default 12).
    first_seed : int
        First seed (default 0).

    Raises
    ------
    InputError
        On an unknown plant, no or non-positive speeds or durations, negative noise levels,
        fewer than 1 seed, or process noise asked of the nonlinear plant.
    """

    bicycle: str = "benchmark"
    plant: str = "linear"
    controller: str = "pid"
    speeds: tuple[float, ...] = (5.0,)
    dither: float = 3.0
    dither_hold: int = 5
    disturbance: float = 0.5
    roll_torque: float = 0.0
    angle_noise: float = 1e-3
    rate_noise: float = 1e-2
    durations: tuple[float, ...] = (25.0, 100.0, 400.0)
    seeds: int = 12
    first_seed: int = 0
    sample_time: float = field(default=0.01, repr=False)

    def __post_init__(self) -> None:
        if self.plant not in PLANTS:
            raise InputError(f"plant={self.plant!r}: choose linear or nonlinear")
        object.__setattr__(self, "speeds", _floats("speeds", self.speeds, 0.0))
        object.__setattr__(self, "durations", _floats("durations", self.durations, 0.0))
        for name in ("dither", "disturbance", "roll_torque", "angle_noise", "rate_noise"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"{name}={v!r}: give a finite number >= 0")
            object.__setattr__(self, name, float(v))
        for name, low in (("seeds", 1), ("first_seed", 0), ("dither_hold", 1)):
            v = getattr(self, name)
            if int(v) != v or v < low:
                raise InputError(f"{name}={v!r}: give a whole number >= {low}")
            object.__setattr__(self, name, int(v))
        if self.plant == "nonlinear" and (self.disturbance or self.roll_torque):
            raise InputError(
                "the nonlinear plant models no process noise: give "
                "disturbance=0 and roll_torque=0, or plant='linear'"
            )

    @property
    def against(self) -> str:
        """str: what the truth is: ``"the exact linear model"`` or ``"the linearization"``."""
        return "the exact linear model" if self.plant == "linear" else "the linearization"

    def to_json(self) -> dict[str, Any]:
        """Every field as plain JSON values.

        Returns
        -------
        dict
            The fields by name (tuples as lists).
        """
        d = asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    def seed_list(self) -> list[int]:
        """The seeds, from ``first_seed`` to ``first_seed + seeds - 1``.

        Returns
        -------
        list of int
            The seeds.
        """
        return list(range(self.first_seed, self.first_seed + self.seeds))

    def runs(self, duration: float, seed: int) -> list:
        """The runs of one seed: one per speed, in the order of :attr:`speeds`.

        Parameters
        ----------
        duration : float
            Record length [s].
        seed : int
            The seed.

        Returns
        -------
        list of Run
            :func:`closed_loop_run` at each speed k with random seed
            ``seed * len(speeds) + k``.
        """
        n = len(self.speeds)
        return [closed_loop_run(self, v, duration, seed * n + k) for k, v in enumerate(self.speeds)]


def closed_loop_run(scenario: Scenario, speed: float, duration: float, seed: int):
    """One closed-loop run of a scenario's plant, controller, dither and noise.

    Parameters
    ----------
    scenario : Scenario
        The scenario (its speeds and durations are not used here).
    speed : float
        Forward speed [m/s].
    duration : float
        Record length [s].
    seed : int
        Random seed of the dither, process noise and sensor noise.

    Returns
    -------
    Run
        The logged run (``run.dither`` the dither [N m]; ``run.truth`` the true states on
        the linear plant).

    Raises
    ------
    ValueError
        If the controller does not keep the bicycle upright (raised by the simulators).
    """
    # lazy: `bikeid --help` imports the coverage defaults; numerics load on first use
    from bikeid.controllers.registry import make
    from bikeid.sim.parameters import by_name

    p = by_name(scenario.bicycle)
    controller = make(scenario.controller, p, sample_time=scenario.sample_time)
    if scenario.plant == "linear":
        from bikeid.dataset.linear_loop import simulate

        return simulate(
            p,
            float(speed),
            duration=float(duration),
            controller=controller,
            seed=int(seed),
            dither=scenario.dither,
            dither_hold=scenario.dither_hold,
            disturbance=scenario.disturbance,
            roll_torque=scenario.roll_torque,
            angle_noise=scenario.angle_noise,
            rate_noise=scenario.rate_noise,
        )
    from bikeid.controllers import UniformDither
    from bikeid.dataset.closed_loop import simulate_run
    from bikeid.dataset.sensors import ANGLES, RATES, Channel, Sensors

    chans = {n: Channel(std=scenario.angle_noise) for n in ANGLES}
    chans.update({n: Channel(std=scenario.rate_noise) for n in RATES})
    dither = UniformDither(
        scenario.dither,
        hold=scenario.dither_hold * scenario.sample_time,
        seed=int(seed),
        max_amplitude=max(1.0, scenario.dither),
    )
    return simulate_run(
        p,
        controller,
        float(speed),
        float(duration),
        dither=dither,
        sensors=Sensors(chans, 1.0 / scenario.sample_time),
        seed=int(seed),
        plant="nonlinear",
    )


def true_modes(scenario: Scenario) -> dict[float, np.ndarray]:
    """The truth an estimate is scored against: per speed the weave (positive imaginary
    part), its conjugate, capsize and caster eigenvalues [1/s] of the linear model.

    Parameters
    ----------
    scenario : Scenario
        The scenario (bicycle and speeds).

    Returns
    -------
    dict of float to ndarray
        Speed [m/s] -> (4,) complex [weave, conj(weave), capsize, caster].

    Raises
    ------
    InputError
        If at a speed the bicycle lacks a weave pair with two real roots.
    """
    from bikeid.experiments.testbed.accuracy import true_modes as modes_of
    from bikeid.sim.parameters import by_name

    out = {}
    table = modes_of(by_name(scenario.bicycle), list(scenario.speeds))
    for v in scenario.speeds:
        m = table[round(v, 6)]
        if set(m) != {"weave", "capsize", "caster"}:
            raise InputError(
                f"at {v:g} m/s {scenario.bicycle} has modes {sorted(m)}, not a "
                "weave pair, capsize and caster; choose another speed"
            )
        out[v] = np.array([m["weave"], np.conj(m["weave"]), m["capsize"], m["caster"]])
    return out
