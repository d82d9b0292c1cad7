"""``bikeid measured discover``: terms of the equations of motion the decays support.

The inputs are those of ``measured fit`` (logs with the import options or the steer-by-wire
folder, ``--bicycle``, ``--plant``, ``--speeds``, ``--decays``; the same option helpers and
loader), or ``--model FIT.json`` to start from a fitted model's residual.  The search is
:func:`bikeid.ident.effects.discovery.discover`; ``--out`` writes the kept terms as an
effects file that ``measured fit|evaluate --effects-file`` accept.
"""

from __future__ import annotations

import argparse
import sys

from bikeid.experiments.cli.args import dump_json, integer, number, range_text

__all__ = ["cmd_discover", "register"]


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``discover`` to the ``measured`` subcommands (registered before this module).

    Parameters
    ----------
    sub : argparse._SubParsersAction
        ``bikeid``'s subparsers, holding ``measured`` (its ``subcommands``).
    """
    from bikeid.experiments.cli.measured import (
        DATA_HELP,
        DECAYS_HELP,
        add_effects_file_option,
        add_log_options,
        uncertainty_arg,
    )

    msub = sub.choices["measured"].subcommands
    d = msub.add_parser(
        "discover", help="name terms of the roll/steer equations the decays support"
    )
    d.add_argument("--data", help=DATA_HELP)
    add_log_options(d)
    d.add_argument(
        "--model", metavar="FIT.json",
        help="start from this 'measured fit' model (its effects, bicycle, experiment and "
        "plant) instead of the nominal",
    )  # fmt: skip
    d.add_argument(
        "--speeds", type=range_text("--speeds", 0.0),
        help="treadmill speeds to use [m/s], e.g. 1.5,3.5 (default all)",
    )  # fmt: skip
    d.add_argument("--decays", choices=("listed", "detected"), default="listed", help=DECAYS_HELP)
    d.add_argument(
        "--plant", choices=("nonlinear", "linear"), default=None,
        help="nominal plant: nonlinear (defect-corrected; default, or the --model's plant) or "
        "linear",
    )  # fmt: skip
    d.add_argument(
        "--max-terms",
        type=integer(1, 20),
        default=3,
        help="at most this many terms (rounds of the search; default 3)",
    )
    d.add_argument(
        "--alpha", type=number(0.0, 1.0, lo_open=True, hi_open=True), default=0.05,
        metavar="A",
        help="family-wise error rate over every test of the search (Bonferroni over terms x "
        "rounds; default 0.05)",
    )  # fmt: skip
    d.add_argument(
        "--nominal-uncertainty", type=uncertainty_arg, default="default", metavar="U",
        help="the stated bicycle's uncertainty, as for 'measured fit': its inertias and "
        "trail are calibrated within it, and a term must stay significant with them refitted "
        "('default': each body's inertia tensor +-5 %%, trail +-2 mm; 'none': the bicycle "
        "taken as exact; or inertia=F,trail=M)",
    )  # fmt: skip
    add_effects_file_option(d, "known to the model (not tried again)")
    d.add_argument(
        "--out", metavar="FILE", help="write the kept terms as an effects file (.yaml or .json)"
    )
    d.add_argument("--json", action="store_true", help="print JSON (terms, before_after, test)")
    d.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    d.set_defaults(func=cmd_discover)


def _check_out(args) -> None:
    """``--out``: a .yaml/.yml/.json file that is none of the inputs (before the search)."""
    from bikeid.dataset.files import check_output_path, check_outputs
    from bikeid.sim.errors import InputError

    if args.out is None:
        return
    if not str(args.out).lower().endswith((".yaml", ".yml", ".json")):
        raise InputError(f"--out {args.out}: an effects file is .yaml, .yml or .json; give "
                         "e.g. --out terms.yaml")  # fmt: skip
    check_output_path(args.out)
    inputs = [*(args.file or []), args.data, args.model, args.effects_file]
    check_outputs([args.out], [x for x in inputs if x])


def cmd_discover(args) -> int:
    """Run ``measured discover`` (module docstring)."""
    from bikeid.dataset.decays import MIN_FIT_DECAYS
    from bikeid.experiments.cli.measured import _speeds, load_log_decays, use_effects_file
    from bikeid.experiments.progress import terminal_progress
    from bikeid.ident.effects.acceptance import AcceptanceRule
    from bikeid.ident.effects.discovery import discover
    from bikeid.ident.effects.pipeline import simulable_windows

    _check_out(args)
    use_effects_file(args)
    experiment, start, plant = None, None, "nonlinear"
    if args.model:
        from bikeid.dataset.files import check_input_file
        from bikeid.ident.effects.pipeline import model_from_json

        check_input_file(args.model, "--model")
        start, obj = model_from_json(args.model)
        experiment, plant = obj.get("experiment") or {}, obj["plant"]
    plant = args.plant or plant
    ws, base, _law, _report = load_log_decays(args, _speeds(args.speeds),
                                              min_decays=MIN_FIT_DECAYS,
                                              purpose="the discovery",
                                              experiment=experiment)  # fmt: skip
    model = start if start is not None else base
    nonlinear = plant == "nonlinear"
    dropped: list[dict] = []
    if nonlinear:
        ws, dropped = simulable_windows(model, ws)
    if len(ws) < MIN_FIT_DECAYS:
        from bikeid.sim.errors import InputError

        raise InputError(f"only {len(ws)} decays the {plant} plant can simulate; discovery "
                         f"needs {MIN_FIT_DECAYS} (give more logs or --plant linear)")  # fmt: skip
    bar = terminal_progress("measured discover", unit="fit",
                            quiet=args.quiet or args.json)  # fmt: skip
    rule = AcceptanceRule(alpha=args.alpha, nominal_uncertainty=args.nominal_uncertainty)
    res = discover(model, ws, nonlinear=nonlinear, max_terms=args.max_terms, rule=rule,
                   progress=bar)  # fmt: skip
    out = {**res.as_dict(), "plant": plant, "decays": len(ws), "dropped_windows": dropped,
           "start": args.model or "nominal"}  # fmt: skip
    if args.out:
        res.effects_file(args.out)
        out["effects_file"] = str(args.out)
        if not args.quiet:
            print(f"measured discover: wrote {args.out}", file=sys.stderr, flush=True)
    if args.json:
        print(dump_json(out))
        return 0
    t = res.test
    print(f"decays: {len(ws)} ({plant} plant; {len(dropped)} dropped); {len(t['dictionary'])} "
          f"terms x {args.max_terms} rounds = {t['tests']} tests at level {t['level']:.2g} "
          f"(family-wise {t['alpha']:g}, Bonferroni)")  # fmt: skip
    if not res.terms:
        print("terms: none found")
        return 0
    from bikeid.ident.effects.before_after import verdict_text

    for d in res.terms:
        lo, hi = d["interval"]
        alike = ", ".join(f"{a['equation']}: {a['term']}" for a in d["indistinguishable"])
        print(f"{d['equation']}: {d['coefficient']:+.4g} * {d['term']} [{d['unit']}] "
              f"(95 % {lo:+.4g}..{hi:+.4g}, p = {d['p_value']:.2g}): {d['reading']}"
              + (f"; indistinguishable: {alike}" if alike else ""))  # fmt: skip
    print(f"held-out half (used to choose the terms, not out of sample): "
          f"{verdict_text(res.before_after)}")  # fmt: skip
    return 0
