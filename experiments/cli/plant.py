"""Plant commands: ``eig``, ``linearize``, ``critical-speeds`` (and ``simulate``)."""

from __future__ import annotations

import argparse

from bikeid.experiments.cli.args import (
    atomic_write_text,
    check_figure_path,
    dump_json,
    parse_range,
    range_text,
    speed_value,
)

BICYCLE_HELP = (
    "bicycle: 'benchmark' (Meijaard 2007), 'steer-by-wire', a bicycleparameters name "
    "(Browser, Rigid, Pista, Fisher, ...) or a .yaml/.json parameter file"
)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eig", help="eigenvalues against speed (weave, capsize, caster)")
    p.add_argument("--bicycle", default="benchmark", help=BICYCLE_HELP)
    p.add_argument(
        "--speeds",
        type=range_text("--speeds", 0.0),
        default="0:10:0.1",
        help="start:stop:step [m/s], stop included (at most 100 m/s)",
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--plot", metavar="FILE", help="write a figure of the real and imaginary "
                   "parts, in the format its suffix names (.png, .pdf, .svg, .eps, .ps)")
    p.set_defaults(func=cmd_eig)

    p = sub.add_parser("linearize", help="M, C1, K0, K2, A, B and eigenvalues at one speed")
    p.add_argument("--bicycle", default="benchmark", help=BICYCLE_HELP)
    p.add_argument("--speed", type=speed_value, required=True,
                   help="forward speed [m/s, or with a unit: 18km/h], 0-100")
    p.add_argument("--json", action="store_true", help="print JSON (default: text)")
    p.set_defaults(func=cmd_linearize)

    p = sub.add_parser("critical-speeds", help="v_d, v_w, v_c by root finding")
    p.add_argument("--bicycle", default="benchmark", help=BICYCLE_HELP)
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(func=cmd_critical_speeds)


def _bicycle(name: str):
    """The bicycle of ``--bicycle``; a value bikeid adjusted is said as a note on stderr."""
    import sys
    import warnings

    from bikeid.sim.parameters import ParameterAdjusted, by_name

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ParameterAdjusted)
        p = by_name(name)
    for w in caught:
        if issubclass(w.category, ParameterAdjusted):
            print(f"note: {w.message}", file=sys.stderr)
        else:  # not ours to turn into a note: pass it on unchanged
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return p


def cmd_eig(args: argparse.Namespace) -> int:
    from bikeid.sim.linear import eigenvalues_vs_speed

    speeds = parse_range(args.speeds, "--speeds", minimum=0.0)
    if args.plot:  # before any work: a link or device refused, the parameter file never hit
        from bikeid.dataset.files import check_output_path, check_outputs

        check_output_path(args.plot)
        check_outputs([args.plot], [args.bicycle])
        check_figure_path(args.plot, "--plot")
    p = _bicycle(args.bicycle)
    sweep = eigenvalues_vs_speed(p, speeds)
    if args.plot:
        from bikeid.experiments.plots import plot_eigenvalues

        plot_eigenvalues(sweep, args.plot, title=f"{p.name}: eigenvalues against speed")
    if args.json:
        out = {
            "bicycle": p.name,
            "speeds": sweep.speeds,
            "labels": list(sweep.labels),
            "eigenvalues": [list(row) for row in sweep.values],
        }
        print(dump_json(out))
    else:
        head = "  ".join(f"{lab:>22s}" for lab in sweep.labels)
        print(f"{'v [m/s]':>8s}  {head}")
        for v, row in zip(sweep.speeds, sweep.values, strict=True):
            cells = "  ".join(f"{z.real:+11.6f}{z.imag:+10.6f}j" for z in row)
            print(f"{v:8.3f}  {cells}")
    return 0


def cmd_linearize(args: argparse.Namespace) -> int:
    import numpy as np

    from bikeid.sim.linear import canonical_matrices, state_matrices

    p = _bicycle(args.bicycle)
    cm = canonical_matrices(p)
    A, B = state_matrices(cm, args.speed)
    out = {
        "bicycle": p.name,
        "speed": args.speed,
        "state": ["phi", "delta", "phidot", "deltadot"],
        "inputs": ["T_phi", "T_delta"],
        "M": cm.M, "C1": cm.C1, "K0": cm.K0, "K2": cm.K2, "g": cm.g,
        "A": A, "B": B,
        "eigenvalues": sorted(np.linalg.eigvals(A), key=lambda z: (z.real, z.imag)),
    }  # fmt: skip
    if args.json:
        print(dump_json(out))
    else:
        np.set_printoptions(precision=10, suppress=False, linewidth=120)
        for key in ("M", "C1", "K0", "K2", "A", "B"):
            print(f"{key} =\n{out[key]}")
        print("eigenvalues =", np.array(out["eigenvalues"]))
    return 0


def cmd_critical_speeds(args: argparse.Namespace) -> int:
    from bikeid.sim.linear import critical_speeds

    p = _bicycle(args.bicycle)
    cs = critical_speeds(p)
    if args.json:
        print(dump_json({"bicycle": p.name, **cs}))
    else:
        for key, label in (("v_d", "weave becomes oscillatory"), ("v_w", "weave speed"),
                           ("v_c", "capsize speed")):  # fmt: skip
            val = cs[key]
            txt = "none below 30 m/s" if val is None else f"{val:.4f} m/s"
            print(f"{key} = {txt}  ({label})")
        if cs["weave_frequency"] is not None:
            print(f"weave frequency at v_w = {cs['weave_frequency']:.4f} rad/s")
    return 0


def write_json(path: str, obj) -> None:
    atomic_write_text(path, dump_json(obj) + "\n")
