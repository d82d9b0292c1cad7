"""Closed-loop runs: plant + controller + reference + dither + sensors + effects -> Run.

One vocabulary for both plants: the nonlinear Whipple plant (default) or, with
``simulate_run(..., plant="linear")``, the exact zero-order-hold linear plant
(:func:`dataset.linear_loop.run_loop`) under the same controller, sensor and dither
objects and the same sampled loop below.

The loop, per controller sample t_j = j * Ts (Ts = ``controller.sample_time``)::

    y_true(t_j)  --anti-alias (optional, at every controller sample)-->
                 --sensors at sensor instants t_k = k / rate, held in between--> y_meas
    T_delta(t_j) = controller(t_j, y_meas) + dither(t_j)        (held over [t_j, t_j+1))

so the controller sees only measured signals, and the sensor period must be a whole
multiple of the controller period (a controller slower than its sensors would leave sensor
samples nobody computed: refused with a ValueError).  The run is sampled at the sensor
rate and records, at each sensor instant t_k:

- ``signals``: exactly the measured vector the controller received (MEASURED channels) and
  the logged steer torque ``T_delta`` (the command incl. dither, through the sensor model's
  ``T_delta`` channel if it has one; exact by default);
- ``truth``: the true MEASURED signals, the torque applied from t_k on (after input-side
  effects, when the plant reports it), pitch ``theta`` and rear contact ``x``, ``y``;
- ``dither`` [N m] and ``reference`` [rad] at t_k;
- ``meta["sampling"]``: ``controller_period`` Ts, ``logging_period`` (the sensor period)
  and ``dither_hold`` [s] (the dither's ``hold`` attribute, None if it has none).

Sampling contract: the logged T_delta at t_k is the command computed at t_k; it is the
torque the plant held over the whole logging interval only if the controller runs at the
logging period (the default: every controller's ``sample_time`` defaults to
``controllers.DEFAULT_SAMPLE_TIME`` = 0.01 s, the default sensors' period) and the dither
is held a whole number of logging periods (``UniformDither`` defaults to 0.01 s).  A
faster controller can be asked for explicitly (e.g. to study the loop at 1 kHz); its runs
record both periods and the estimators refuse them (``ident.signals.check_sampling``).

The speed is held by the plant's ideal rear drive (``mode="held"``, the default) or
coasts (``mode="coast"``).  A run that ends early (``sim.integrate.STOP_CAUSES``: a fall,
|steer| over 90 deg, or a numerical failure such as a step too coarse for the dynamics)
is kept, truncated before the stop, with ``meta["stop"]`` = ``{cause, time, message,
physical}`` (None if the run is complete) and ``meta["fell_at"]`` [s] set for physical
stops only (None if upright or if the run failed numerically).  Estimators refuse such
runs (``ident.signals.check_complete``).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from bikeid.sim.conventions import MEASURED
from bikeid.sim.errors import UntrustworthyResult, check_memory
from bikeid.sim.integrate import simulate
from bikeid.sim.nonlinear import WhippleBicycle
from bikeid.sim.parameters import BicycleParameters

from .linear_loop import _describe, run_loop
from .run import Run
from .sensors import Sensors, channel_noise
from .store import package_version

__all__ = ["PLANTS", "simulate_run"]

#: Plants :func:`simulate_run` runs (``plant=``).
PLANTS = ("nonlinear", "linear")


class SampledLoop:
    """The controller callable handed to the integrator (see the module docstring).

    Records y_true, y_meas, the commanded torque and the dither at sensor instants.
    """

    def __init__(
        self,
        controller: Callable[[float, Sequence[float]], float],
        sensors: Sensors,
        seed: int,
        ctrl_dt: float,
        n_sensor: int,
        dither: Callable[[float], float] | None,
    ) -> None:
        self.controller = controller
        self.dither = dither
        self.ctrl_dt = ctrl_dt
        self.m = sensors.decimation(ctrl_dt)
        self.chain = sensors.chain(seed, n_sensor, MEASURED, fine_dt=ctrl_dt)
        nm = len(MEASURED)
        self.y_true = np.zeros((n_sensor, nm))
        self.y_meas = np.zeros((n_sensor, nm))
        self.u = np.zeros(n_sensor)
        self.t = np.zeros(n_sensor)
        self.d = np.zeros(n_sensor)
        self.n_rec = 0
        self._t_last: float | None = None
        self._u_last = 0.0
        self._meas = None

    def __call__(self, t: float, y: Sequence[float]) -> float:
        if t == self._t_last:
            return self._u_last
        j = round(t / self.ctrl_dt)
        y = np.asarray(y, dtype=float)
        yf = self.chain.filter(y)
        k, r = divmod(j, self.m)
        if r == 0 and k < self.u.size:
            meas = self.chain(k, yf)
            self._meas = meas
            self.y_true[k] = y
            self.y_meas[k] = meas
        elif self._meas is None:
            raise ValueError(f"controller first called at t={t} s, off the sensor grid")
        u = float(self.controller(t, self._meas.tolist()))
        d = float(self.dither(t)) if self.dither is not None else 0.0
        u += d
        if r == 0 and k < self.u.size:
            self.u[k] = u
            self.t[k] = t
            self.d[k] = d
            self.n_rec = k + 1
        self._t_last = t
        self._u_last = u
        return u


def simulate_run(
    p: BicycleParameters,
    controller,
    speed: float,
    duration: float = 50.0,
    reference: Callable[[float], float] | None = None,
    dither: Callable[[float], float] | None = None,
    sensors: Sensors | None = None,
    effects: Sequence[Any] = (),
    seed: int = 0,
    mode: str = "held",
    initial: dict[str, float] | None = None,
    lateral_force: Callable[[float], float] | None = None,
    plant: str = "nonlinear",
    **integrator_options: Any,
) -> Run:
    """Simulate one closed-loop run of ``duration`` [s] at ``speed`` [m/s].

    The nonlinear Whipple plant (``sim.nonlinear.WhippleBicycle``) is integrated by
    ``sim.integrate.simulate`` under the controller, sampled as described in the module
    docstring.  With ``plant="linear"`` the same controller, reference, dither, sensors
    and lateral force drive the exact zero-order-hold linear plant instead
    (:func:`dataset.linear_loop.run_loop`: x[k+1] = Ad x[k] + Bd u[k] at the controller
    period, speed held, the lateral force at the rear body's mass centre as in the
    nonlinear plant); it takes no effects and no integrator options.

    Parameters
    ----------
    p : BicycleParameters
        The bicycle's parameters (Meijaard 2007 notation, SI units).
    controller : controllers.base.ControllerLike
        A ``controllers`` controller (``sample_time`` [s], ``reset()``,
        ``__call__(t, y)`` -> T_delta [N m], ``describe()``); its ``sample_time`` should
        be the sensor period, the default, for the run to be identifiable (module
        docstring).  It is reset before the run.
    speed : float
        Forward speed [m/s], positive; held by the rear drive (``mode="held"``) or the
        initial speed (``mode="coast"``).
    duration : float, optional
        Run length [s], positive (default 50).
    reference : callable, optional
        Roll reference t [s] -> phi_ref [rad], installed as ``controller.reference``
        (the controller keeps it after the run); None keeps the controller's own.
    dither : callable, optional
        Steer-torque dither t [s] -> [N m] added to the command (positive to the right);
        None for none.
    sensors : Sensors, optional
        The instruments (default :meth:`Sensors.default`, 100 Hz); their period must be a
        whole multiple of the controller period.
    effects : sequence, optional
        ``sim.effects`` objects acting on the plant or its steer-torque input.
    seed : int, optional
        Sensor-noise seed (the dither carries its own seed).
    mode : {"held", "coast"}, optional
        Speed held by the ideal rear drive (default) or coasting.
    initial : dict of str to float, optional
        Initial values with keys ``phi``, ``delta`` [rad], ``phidot``, ``deltadot``
        [rad/s]; default upright at rest in roll and steer.
    lateral_force : callable, optional
        Lateral force t [s] -> F [N] (positive to the right) on the rear frame, sampled on
        the controller grid; None for none.
    plant : {"nonlinear", "linear"}, optional
        The nonlinear Whipple plant (default) or the exact ZOH linear one.
    **integrator_options
        Passed to ``sim.integrate.simulate`` (``substeps``, ``fall_limit``, ``method``,
        ``energy``); ``controller``, ``dt``, ``inputs``, ``measure``, ``effects`` and
        ``mode`` are set here and may not be passed.

    Returns
    -------
    Run
        Sampled at the sensor instants t_k [s] (length n, truncated at a fall):
        ``signals`` has the measured :data:`sim.conventions.MEASURED` channels exactly as
        the controller received them, the logged ``T_delta`` [N m] and, with a lateral
        force, the load cell's ``F`` [N]; ``truth`` has the true MEASURED channels, the
        applied ``T_delta`` [N m] (and ``F`` [N]), pitch ``theta`` [rad] and contact
        points ``x``, ``y``, ``xF``, ``yF`` [m] (linear plant: instead the exact
        accelerations ``phiddot``, ``deltaddot`` [rad/s^2]); ``dither`` [N m] and
        ``reference`` [rad] at t_k; ``meta`` with the speed, seed, ``fell_at`` [s] (None
        if upright), the bicycle, the descriptions of controller, reference, dither, lateral force,
        sensors and effects, ``sampling`` (``controller_period``, ``logging_period``,
        ``dither_hold`` [s]) and ``plant``.

    Raises
    ------
    ValueError
        If ``speed`` or ``duration`` is not positive and finite, the sensors are faster
        than the controller or their period is not a whole multiple of it, ``initial``
        has an unknown key, an integrator option set here is passed, ``plant`` is
        unknown, or the linear plant is given effects, ``mode="coast"`` or integrator
        options.
    UntrustworthyResult
        If the run ended (fell) before its second sensor sample, or the linear plant left
        the small-angle range (|phi| or |delta| > 1 rad).
    """
    if plant not in PLANTS:
        raise ValueError(f"plant={plant!r}: choose one of {', '.join(PLANTS)}")
    speed = float(speed)
    if not (math.isfinite(speed) and speed > 0):
        raise ValueError(f"speed must be > 0 m/s, got {speed}")
    duration = float(duration)
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"duration must be > 0 s, got {duration}")
    sensors = Sensors.default() if sensors is None else sensors
    ctrl_dt = float(controller.sample_time)
    if sensors.dt < ctrl_dt * (1 - 1e-9):
        raise ValueError(
            f"sensor rate {sensors.rate} Hz is faster than the controller "
            f"({1 / ctrl_dt:g} Hz); run the controller at least as fast as its sensors"
        )
    if reference is not None:
        controller.reference = reference
    controller.reset()
    check_memory(duration / ctrl_dt + 1, 45, f"a {duration:g} s closed-loop run at "
                 f"{1 / ctrl_dt:g} Hz", "shorten the duration")  # loop records + trajectory
    n_sensor = int(round(duration * sensors.rate)) + 1
    loop = SampledLoop(controller, sensors, seed, ctrl_dt, n_sensor, dither)
    if plant == "linear":
        traj = _linear(
            p, loop, speed, duration, ctrl_dt, effects, mode, initial, lateral_force,
            integrator_options,
        )  # fmt: skip
    else:
        traj = _integrate(
            p, loop, speed, duration, ctrl_dt, effects, mode, initial, lateral_force,
            integrator_options,
        )  # fmt: skip
    n = loop.n_rec
    while n > 0 and not math.isfinite(loop.u[n - 1]):  # the sample where the controller failed
        n -= 1
    if n < 2:
        raise UntrustworthyResult(
            f"the run at {speed:g} m/s ended after {n} sensor sample(s): {traj.stop_reason}; "
            "no data to record: start closer to upright or use a controller that stabilizes "
            "this speed"
        )
    t = loop.t[:n].copy()  # the instants the controller was called at
    signals = {name: loop.y_meas[:n, i].copy() for i, name in enumerate(MEASURED)}
    truth = {name: loop.y_true[:n, i].copy() for i, name in enumerate(MEASURED)}
    torque = loop.u[:n].copy()
    ch = sensors.channel("T_delta")
    signals["T_delta"] = torque if ch.ideal else ch.apply(torque, channel_noise(seed, "T_delta", n))
    truth.update(traj.extras(t) if plant == "linear" else _trajectory_extras(traj, t))
    if "F" in truth:  # a load cell logs the applied lateral force (Moore & Hubbard's F_cl)
        chf = sensors.channel("F")
        signals["F"] = (
            truth["F"] if chf.ideal else chf.apply(truth["F"], channel_noise(seed, "F", n))
        )
    ref = controller.reference
    reference_arr = np.array([float(ref(tk)) for tk in t])
    fell_at = None if traj.fell_at is None else float(traj.fell_at)  # physical stops only
    meta = {
        "source": "simulated",
        "bikeid_version": package_version(),
        "speed": speed,
        "duration": duration,
        "seed": int(seed),
        "fell_at": fell_at,
        "stop": None if traj.stop is None else traj.stop.as_dict(),
        "bicycle": {"name": getattr(p, "name", "custom"), "parameters": p.as_dict()},
        "controller": controller.describe(),
        "reference": _describe(ref),
        "dither": _describe(dither),
        "lateral_force": _describe(lateral_force),
        "sensors": sensors.describe(),
        "sampling": {
            "controller_period": ctrl_dt,
            "logging_period": float(sensors.dt),
            "dither_hold": None if getattr(dither, "hold", None) is None else float(dither.hold),
        },
        "effects": [_describe(e) for e in effects],
        "plant": {"model": f"whipple-{plant}", "initial": initial or {}, **traj.meta},
    }
    return Run(
        t=t,
        signals=signals,
        truth=truth,
        dither=loop.d[:n].copy(),
        reference=reference_arr,
        meta=meta,
    )


def _integrate(
    p, loop, speed, duration, ctrl_dt, effects, mode, initial, lateral_force, options
):
    """Run ``sim.integrate.simulate`` with ``loop`` as the controller; returns its Trajectory."""
    bike = WhippleBicycle(p)
    init = _initial_state(initial)
    x0 = bike.state(speed, **init)
    inputs = None
    if lateral_force is not None:
        n = int(round(duration / ctrl_dt)) + 1
        inputs = {"F": np.array([float(lateral_force(k * ctrl_dt)) for k in range(n)])}
    options = dict(options)
    for key in ("controller", "dt", "inputs", "measure", "effects", "mode"):
        if key in options:
            raise ValueError(f"integrator option {key!r} is set by simulate_run; do not pass it")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        traj = simulate(
            bike, x0, duration, controller=loop, dt=ctrl_dt, mode=mode, inputs=inputs,
            effects=list(effects) or None, **options,
        )  # fmt: skip
    for w in caught:  # the stop's own warning is recorded in meta["stop"]; pass on the rest
        if traj.stop is None or str(w.message) != traj.stop.message:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return traj


def _initial_state(initial: dict[str, float] | None) -> dict[str, float]:
    init = dict(initial or {})
    unknown = set(init) - {"phi", "delta", "phidot", "deltadot"}
    if unknown:
        raise ValueError(
            f"unknown initial values {sorted(unknown)}; use phi, delta, phidot, deltadot"
        )
    return init


class _LinearTrajectory:
    """What :func:`simulate_run` reads of a plant's trajectory, for the linear plant."""

    stop = None
    fell_at = None

    def __init__(self, out: dict[str, np.ndarray], dt: float, meta: dict[str, Any]) -> None:
        self.out = out
        self.dt = dt
        self.meta = meta
        self.stop_reason = "the linear loop stopped"

    def extras(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """Applied inputs and exact accelerations at the sensor instants ``t`` [s]."""
        idx = np.rint(t / self.dt).astype(int)
        out = {"T_delta": self.out["T_delta"][idx]}
        if np.any(self.out["F"] != 0):
            out["F"] = self.out["F"][idx]
        for name in ("phiddot", "deltaddot"):
            out[name] = self.out[name][idx]
        return out


def _linear(p, loop, speed, duration, ctrl_dt, effects, mode, initial, lateral_force, options):
    """The exact ZOH linear plant (``linear_loop.run_loop``) under ``loop``."""
    if mode not in ("held", "coast"):
        raise ValueError(f"mode {mode!r} unknown; use 'coast' or 'held'")  # as the nonlinear
    for what, bad, fix in (
        ("effects", bool(list(effects)), "drop them"),
        ("mode='coast'", mode == "coast", "the linear plant holds the speed"),
        (f"integrator options {sorted(options)}", bool(options), "drop them"),
    ):
        if bad:
            raise ValueError(f"plant='linear' takes no {what}; {fix}, or use plant='nonlinear'")
    init = _initial_state(initial)
    x0 = [float(init.get(k, 0.0)) for k in ("phi", "delta", "phidot", "deltadot")]
    n = int(round(duration / ctrl_dt)) + 1
    force = None
    if lateral_force is not None:
        force = np.array([float(lateral_force(k * ctrl_dt)) for k in range(n)])
    out = run_loop(p, loop, speed, n, ctrl_dt, x0, force)
    angles = np.abs(np.column_stack([out["phi"], out["delta"]]))
    if not np.all(np.isfinite(angles)) or angles.max() > 1.0:
        raise UntrustworthyResult(
            f"the linear loop left the small-angle range (max |angle| "
            f"{np.nanmax(angles):.3g} rad) at v={speed:g} m/s; reduce dither or noise, or check "
            "that the controller stabilizes this bicycle"
        )
    meta = {"engine": "exact zero-order hold (dataset.linear_loop.run_loop)",
            "lateral_force_point": [float(p.xB), float(p.zB)]}  # fmt: skip
    return _LinearTrajectory(out, ctrl_dt, meta)


def _trajectory_extras(traj, t: np.ndarray) -> dict[str, np.ndarray]:
    """Applied inputs, pitch and contact positions of the trajectory at sensor instants."""
    tt = np.asarray(traj.t, dtype=float)
    idx = np.rint(t / (tt[1] - tt[0])).astype(int)
    if idx.max() >= tt.size or not np.allclose(tt[idx], t, rtol=0, atol=1e-9):
        raise ValueError("plant trajectory does not contain the sensor instants")  # a bug
    out = {"T_delta": traj.signal("T_delta")[idx]}
    if np.any(traj.signal("F") != 0):
        out["F"] = traj.signal("F")[idx]
    for name in ("theta", "x", "y", "xF", "yF"):
        out[name] = np.asarray(traj.signal(name), dtype=float)[idx]
    return out
