"""``bikeid simulate``: one nonlinear Whipple run written to CSV or JSON.

Initial angles and rates are given in degrees (and deg/s); the file holds SI
units (rad, rad/s, m/s, N m) in the columns of :meth:`sim.integrate.Trajectory.columns`.
A run that ends early (a fall, or a numerical failure such as a step too coarse for
the dynamics: ``sim.integrate.STOP_CAUSES``) is reported in one line naming the cause;
the samples before the stop are written, nothing after it.  A numerical failure (not a
fall) ends with exit status 4 (no trustworthy answer), a fall with 0.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from bikeid.experiments.cli.args import (
    atomic_write_text,
    dump_json,
    duration_value,
    integer,
    number,
    speed_value,
    to_jsonable,
)
from bikeid.sim.errors import InputError, UntrustworthyResult

#: Initial angles [deg], initial rates [deg/s], steer torque [N m]: finite, bounded.
ANGLE = number(-90.0, 90.0, unit="deg")
RATE = number(-1e4, 1e4, unit="deg/s")
TORQUE = number(-1e3, 1e3, unit="N m")

BICYCLE_HELP = (
    "bicycle: 'benchmark' (Meijaard 2007), 'steer-by-wire', a bicycleparameters name "
    "or a .yaml/.json parameter file"
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="simulate the nonlinear Whipple bicycle (fixed-step RK4, ZOH controller)",
        description=(
            "Simulate the nonlinear Carvallo-Whipple bicycle.  Signs: Meijaard 2007 "
            "(roll, steer positive to the right).  Steer control: a constant steer torque "
            "or roll-rate feedback T_delta = K * phidot (K > 0 steers into the fall; "
            "K = 10 N m s/rad stabilizes the benchmark at 2-6 m/s)."
        ),
    )
    p.add_argument("--bicycle", default="benchmark", help=BICYCLE_HELP)
    p.add_argument(
        "--speed", type=speed_value, required=True,
        help="initial forward speed [m/s, or with a unit: 18km/h], 0-100",
    )
    p.add_argument("--duration", type=duration_value, required=True, help="simulated time [s]")
    p.add_argument("--phi0", type=ANGLE, default=0.0, help="initial roll [deg]")
    p.add_argument("--delta0", type=ANGLE, default=0.0, help="initial steer [deg]")
    p.add_argument("--phidot0", type=RATE, default=0.0, help="initial roll rate [deg/s]")
    p.add_argument("--deltadot0", type=RATE, default=0.0, help="initial steer rate [deg/s]")
    p.add_argument(
        "--mode", choices=("coast", "held"), default="coast",
        help="coast: free rear wheel; held: ideal drive holds the speed (default coast)",
    )  # fmt: skip
    ctl = p.add_mutually_exclusive_group()
    ctl.add_argument("--steer-torque", type=TORQUE, metavar="CONST", help="constant T_delta [N m]")
    ctl.add_argument(
        "--roll-rate-gain", type=number(-1e4, 1e4, unit="N m s/rad"), metavar="K",
        help="T_delta = K * phidot [N m s/rad]",
    )  # fmt: skip
    p.add_argument(
        "--dt", type=number(0.0, 1.0, lo_open=True, unit="s"), default=0.01,
        help="controller sample time [s]",
    )  # fmt: skip
    p.add_argument(
        "--substeps", type=integer(1, 1000), default=2, help="RK4 steps per sample (default 2)"
    )
    p.add_argument(
        "--fall-limit", type=number(0.0, 90.0, lo_open=True, unit="deg"), default=60.0,
        help="|roll| fall limit [deg], in (0, 90]",
    )  # fmt: skip
    p.add_argument(
        "--effects-file", metavar="FILE",
        help="YAML/JSON file declaring extra effects in the law language "
        "(bikeid.sim.effect_files); those given a 'value' act on the plant (a speed factor "
        "of a law is taken at --speed)",
    )  # fmt: skip
    p.add_argument("--energy", action="store_true", help="add the total energy column [J]")
    p.add_argument("--out", required=True, help="output file, .csv or .json")
    p.set_defaults(func=cmd_simulate)


def _file_effects(args: argparse.Namespace) -> tuple[list, dict]:
    """The plant objects of the ``--effects-file`` declarations that give a value, and the
    values carried (none without the option).

    Raises
    ------
    InputError
        For an invalid file, or a declaration with a value that the nonlinear plant cannot
        carry (an acceleration term).
    """
    if not args.effects_file:
        return [], {}
    from bikeid.dataset.files import check_input_file
    from bikeid.sim.effect_files import load_effects_file
    from bikeid.sim.effect_registry import effect
    from bikeid.sim.effects import nonlinear_effects

    check_input_file(args.effects_file, "--effects-file")
    f = load_effects_file(args.effects_file)
    for name in f.values:
        if effect(name).plant_term is None:
            raise InputError(f"{args.effects_file}: effect {name!r}: {effect(name).no_plant}; "
                             "drop its value here")  # fmt: skip
    if not f.values:
        raise InputError(f"{args.effects_file}: no declaration gives a value; add value: X "
                         "to the effects to simulate")  # fmt: skip
    objects, eq = nonlinear_effects(f.values, args.speed, args.dt)
    return objects, eq


def cmd_simulate(args: argparse.Namespace) -> int:
    import numpy as np

    from bikeid.dataset.files import check_output_path, check_outputs
    from bikeid.sim.integrate import simulate
    from bikeid.sim.nonlinear import WhippleBicycle
    from bikeid.sim.parameters import by_name

    out = Path(args.out)
    if out.suffix.lower() not in (".csv", ".json"):
        raise ValueError(f"--out {args.out!r}: use a .csv or .json file (HDF5: bikeid sweep)")
    check_output_path(out)
    check_outputs([out], [args.bicycle])  # a parameter file is an input too
    if abs(args.phi0) >= args.fall_limit:
        raise InputError(
            f"--phi0 {args.phi0} deg is at or beyond the fall limit {args.fall_limit} deg; "
            "start inside it or raise --fall-limit"
        )
    bike = WhippleBicycle(by_name(args.bicycle))
    x0 = bike.state(
        args.speed,
        phi=math.radians(args.phi0),
        delta=math.radians(args.delta0),
        phidot=math.radians(args.phidot0),
        deltadot=math.radians(args.deltadot0),
    )
    if args.roll_rate_gain is not None:
        k = args.roll_rate_gain
        controller, control = (lambda t, y: k * y[4]), {"roll_rate_gain": k}
    elif args.steer_torque is not None:
        T = args.steer_torque
        controller, control = (lambda t, y: T), {"steer_torque": T}
    else:
        controller, control = None, {}
    effects, values = _file_effects(args)
    tr = simulate(
        bike, x0, args.duration, controller=controller, dt=args.dt, substeps=args.substeps,
        mode=args.mode, fall_limit=math.radians(args.fall_limit), energy=args.energy,
        effects=effects or None,
    )  # fmt: skip
    cols = tr.columns()
    meta = {
        **tr.meta,
        **({"effects_file": {"file": args.effects_file, "values": values}} if values else {}),
        "speed": args.speed,
        "initial": {"phi": x0[3], "delta": x0[5], "phidot": x0[7], "deltadot": x0[9]},
        "control": control,
        "fell_at": tr.fell_at,
        "stop_reason": tr.stop_reason,
        "stop": None if tr.stop is None else tr.stop.as_dict(),
    }
    if out.suffix.lower() == ".csv":
        names = list(cols)
        data = np.column_stack([cols[n] for n in names])
        lines = [f"# bikeid simulate: {json.dumps(to_jsonable(meta))}", ",".join(names)]
        lines += [",".join(f"{x:.12g}" for x in row) for row in data]
        atomic_write_text(out, "\n".join(lines) + "\n")
    else:
        atomic_write_text(out, dump_json({"meta": meta, "signals": cols}) + "\n")
    if tr.stop is not None and tr.stop.physical:
        print(f"bikeid: {tr.stop.message} [{tr.stop.cause}]; wrote {len(tr.t)} samples to {out}")
    elif tr.stop is not None:  # a numerical failure: the samples are written, exit status 4
        raise UntrustworthyResult(
            f"stopped early, not a fall [{tr.stop.cause}]: {tr.stop.message}; wrote "
            f"{len(tr.t)} samples (to t={tr.t[-1]:.3f} s, before the failure) to {out}"
        )
    else:
        print(f"wrote {len(tr.t)} samples ({tr.t[-1]:.3f} s) to {out}")
    return 0
