"""Measured-data commands: ``measured fit|evaluate|report`` and ``data fetch``."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from bikeid.experiments.cli.args import (
    MAX_WORKERS,
    dump_json,
    integer,
    mapping_arg,
    number,
    parse_range,
    range_text,
    to_jsonable,
)
from bikeid.experiments.parallel import DASK_HELP
from bikeid.experiments.progress import terminal_progress
from bikeid.sim.errors import InputError

DATA_HELP = "folder holding tudelft-sbw/ (or the folder itself); default $BIKEID_DATA"
DECAYS_HELP = (
    "free-decay windows: 'listed' = eigen/segments.csv rows, detected from the roll rate "
    "for logs it does not list (default); 'detected' = detected for every log"
)


class _RuleHelp(str):
    """Help text whose ``{field}`` names are read from
    :class:`bikeid.ident.effects.acceptance.AcceptanceRule` when argparse formats it (only
    for ``--help``: importing the effect analysis at start-up would slow every command)."""

    def __mod__(self, params):  # argparse formats help as text % params
        from bikeid.ident.effects import acceptance as acc

        r = acc.AcceptanceRule()
        d = {**{k: v for k, v in r.as_dict().items() if k != "nominal_uncertainty"},
             "heldout_gain": r.heldout_gain, "explained_min": acc.EXPLAINED_MIN,
             "explained_min_calibrated": acc.EXPLAINED_MIN_CALIBRATED,
             "residual_max": acc.RESIDUAL_MAX, "instrument_max": acc.INSTRUMENT_MAX}  # fmt: skip
        return str.__mod__(str.format(self, **d), params)


def add_acceptance_options(p: argparse.ArgumentParser) -> None:
    """The acceptance options of the effect selection (docs/measured.md, "Blind trials").

    ``--alpha`` in (0, 1), ``--correction``, ``--min-heldout-gain`` in [0, 1),
    ``--min-improved`` in [0, 1], ``--unexplained-rule``, ``--unexplained-threshold`` (> 0)
    and ``--nominal-uncertainty``: the fields of
    :class:`bikeid.ident.effects.acceptance.AcceptanceRule` (:func:`acceptance_rule` builds
    it; an option not given keeps the rule's default, which the help text reads from it); a
    bad value is a usage error (exit status 2) naming the option and the allowed range.
    """
    p.add_argument(
        "--alpha",
        type=number(0.0, 1.0, lo_open=True, hi_open=True),
        default=None,
        metavar="A",
        help=_RuleHelp("family-wise level of the effect tests (cluster-robust t against "
                       "Student t with G-1 degrees of freedom for G decay windows), in (0, 1) "
                       "(default {alpha})"),  # fmt: skip
    )
    p.add_argument(
        "--correction",
        choices=("bonferroni", "none"),
        default=None,
        help=_RuleHelp("multiple-comparison correction over candidates x rounds: bonferroni "
                       "(each test at alpha / tests) or none (each at alpha) (default "
                       "{correction})"),  # fmt: skip
    )
    p.add_argument(
        "--min-heldout-gain",
        type=number(0.0, 1.0, hi_open=True),
        default=None,
        metavar="G",
        help=_RuleHelp("least fractional cost reduction an effect must bring on the held-out "
                       "decays, in [0, 1) (default {heldout_gain}, the fit gain; the blind "
                       "trials' strict setting is 0.25)"),  # fmt: skip
    )
    p.add_argument(
        "--min-improved",
        type=number(0.0, 1.0),
        default=None,
        metavar="F",
        help=_RuleHelp("least share of the held-out decays whose own cost an effect must "
                       "lower, in [0, 1] (default {min_improved}: only the summed held-out "
                       "cost; the strict setting is 0.75)"),  # fmt: skip
    )
    p.add_argument(
        "--unexplained-rule",
        choices=("instruments", "floor", "coloured", "residual"),
        default=None,
        help=_RuleHelp("how 'unexplained' is decided: final cost over the instruments' floor "
                       "(instruments: coloured noise, drift, quantization, speed wander "
                       "measured on the decays), explained fraction above the "
                       "second-difference (floor) or coloured-noise floor, or final cost over "
                       "the residual's noise floor (residual) (default {unexplained_rule})"),
    )
    p.add_argument(
        "--unexplained-threshold",
        type=number(0.0, lo_open=True),
        default=None,
        metavar="X",
        help=_RuleHelp("threshold of that rule, > 0 (default {instrument_max} for instruments, "
                       "{explained_min_calibrated} for "
                       "floor and coloured, {explained_min} with --nominal-uncertainty none; "
                       "{residual_max} for residual)"),  # fmt: skip
    )
    p.add_argument(
        "--nominal-uncertainty",
        type=uncertainty_arg,
        default="default",
        metavar="U",
        help="the stated bicycle's uncertainty: its inertias and trail are calibrated within "
        "it before any effect is tried, and a parameter or instrument offset within it is "
        "not reported as an effect. 'default': each body's inertia tensor +-5 %%, trail "
        "+-2 mm, gyro offset +-0.01 rad/s, roll angle +-0.005 rad, steer encoder zero "
        "+-0.002 rad; 'none': take the bicycle as exact; or "
        "inertia=F,trail=M,roll_rate_bias=B,roll_angle_bias=B,steer_angle_bias=B",
    )


def uncertainty_arg(text: str):
    """``--nominal-uncertainty``'s argparse type (a usage error names the accepted forms)."""
    from bikeid.ident.effects.nominal_uncertainty import NominalUncertainty  # not at start-up

    try:
        return NominalUncertainty.parse(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def acceptance_rule(args: argparse.Namespace):
    """The :class:`bikeid.ident.effects.acceptance.AcceptanceRule` of
    :func:`add_acceptance_options`' options (an option not given keeps the rule's default).

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options.

    Returns
    -------
    AcceptanceRule
        The rule.
    """
    from bikeid.ident.effects.acceptance import AcceptanceRule  # not at start-up

    given = {k: getattr(args, k) for k in ("alpha", "correction", "min_heldout_gain",
                                           "min_improved", "unexplained_rule",
                                           "unexplained_threshold")}  # fmt: skip
    return AcceptanceRule(nominal_uncertainty=args.nominal_uncertainty,
                          **{k: v for k, v in given.items() if v is not None})  # fmt: skip


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("measured", help="fit/evaluate the experiment model on measured data")
    msub = p.add_subparsers(dest="measured_command", metavar="SUBCOMMAND")
    f = msub.add_parser("fit", help="identify missing effects on some speeds, write MODEL.json")
    f.add_argument("--data", help=DATA_HELP)
    add_log_options(f)
    f.add_argument("--out", required=True, help="model JSON to write")
    f.add_argument(
        "--speeds",
        type=range_text("--speeds", 0.0),
        help="treadmill speeds to fit on [m/s], e.g. 1.5,3.5 (default all)",
    )
    f.add_argument("--max-effects", type=integer(0, 100), default=3)
    f.add_argument("--decays", choices=("listed", "detected"), default="listed", help=DECAYS_HELP)
    f.add_argument(
        "--stability",
        type=integer(0, 100_000),
        default=0,
        metavar="N",
        help="also refit on N random 75 %% subsamples of the decays and report how often each "
        "effect is selected (stability selection; about N x the fit time)",
    )
    f.add_argument(
        "--plant",
        choices=("auto", "nonlinear", "linear"),
        default="auto",
        help="nominal plant: auto (default): select effects with both the linear and the "
        "nonlinear (defect-corrected) Whipple plant and keep the plant whose final model "
        "predicts the decays better (out-of-fold costs, sign-flip paired test at --alpha); "
        "alike fits keep the nonlinear plant when the two selections agree and give "
        "'nominal plant uncertain' when they disagree (about twice the CPU); nonlinear or "
        "linear force one",
    )
    f.add_argument(
        "--weave-weight",
        type=_weave_weight_arg,
        default="auto",
        metavar="W",
        help="weight of the measured weave eigenvalue of each speed (>= 3 decays) in every "
        "fit: 'auto' (default) gives it the nominal model's output-error cost, a number is "
        "the weight, 0 fits the decay signals only (docs/measured.md)",
    )
    add_acceptance_options(f)
    add_effects_file_option(f, "candidates of the selection (those with in_library)")
    f.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    f.set_defaults(func=cmd_fit)
    p.subcommands = msub  # its subcommands, which other modules extend (cli.discover)
    e = msub.add_parser("evaluate", help="error before/after per file and speed")
    e.add_argument(
        "--model",
        required=True,
        help="MODEL.json from 'measured fit', or a model of 'bikeid identify --out' (with "
        "--drive logged)",
    )
    e.add_argument("--data", help=DATA_HELP)
    add_log_options(e)
    e.add_argument(
        "--speeds",
        type=range_text("--speeds", 0.0),
        help="speeds to evaluate (default: those not used in the fit)",
    )
    e.add_argument("--json", action="store_true", help="print JSON")
    e.add_argument("--decays", choices=("listed", "detected"), default="listed", help=DECAYS_HELP)
    add_effects_file_option(e, "known to the model (a model file re-declares its own)")
    e.set_defaults(func=cmd_evaluate)
    t = msub.add_parser(
        "trials", help="randomized undeclared-effect trials on the nonlinear plant (rates)"
    )
    t.add_argument(
        "--n",
        type=integer(1, 100_000),
        default=32,
        help="number of trials (default 32: 4 per effect)",
    )
    t.add_argument("--seed", type=integer(0, 2**32 - 1), default=1, help="grid seed (default 1)")
    t.add_argument(
        "--processes", type=integer(1, MAX_WORKERS), default=2, help="worker processes (default 2)"
    )
    t.add_argument("--dask", metavar="ADDRESS", help=DASK_HELP)
    t.add_argument("--effects", help="comma list of injected effects (default: all)")
    t.add_argument("--linear", action="store_true", help="linear nominal model (for comparison)")
    t.add_argument("--json", action="store_true", help="print all trials and the summary as JSON")
    t.add_argument("--log", help="append each finished trial to this JSON-lines file")
    add_acceptance_options(t)
    t.set_defaults(func=cmd_trials)
    r = msub.add_parser("report", help="write report.md with before/after figures")
    r.add_argument("--model", help="MODEL.json (default: fit on the first and third speeds)")
    r.add_argument("--data", help=DATA_HELP)
    r.add_argument("--out", required=True, help="output folder")
    r.set_defaults(func=cmd_report)
    s = msub.add_parser(
        "study", help="Moore & Hubbard's model comparison on the logs (held-out tables, figures)"
    )
    s.add_argument("--data", help=DATA_HELP)
    s.add_argument("--out", required=True, help="output folder (report.md, study.json, PNGs)")
    s.add_argument("--json", action="store_true", help="print the study as JSON")
    s.add_argument(
        "--fit-effects",
        action="store_true",
        help="refit the effects model with 'measured fit' per split (about 25 s each) instead "
        "of the effect sets documented in docs/measured.md",
    )
    s.add_argument(
        "--quick", action="store_true", help="grey-box with fewer iterations, no Bode part"
    )
    s.set_defaults(func=cmd_study)
    p.set_defaults(func=lambda a: p.print_help() or 2)

    d = sub.add_parser("data", help="measured data files")
    dsub = d.add_subparsers(dest="data_command", metavar="SUBCOMMAND")
    g = dsub.add_parser("fetch", help="download the pinned steer-by-wire logs (needs internet)")
    g.add_argument("--dest", default="data", help="folder to create tudelft-sbw/ in")
    g.add_argument(
        "--all-speeds",
        action="store_true",
        help="also fetch the campaign's free-decay runs at 2, 3, 4 and 5 m/s (more decays "
        "per speed and two more speeds for held-out tests)",
    )
    g.set_defaults(func=cmd_fetch)
    d.set_defaults(func=lambda a: d.print_help() or 2)


def parse_weave_weight(text: str) -> float | str:
    """``--weave-weight``: 'auto' or a finite number >= 0 (a clear error otherwise)."""
    if text == "auto":
        return text
    try:
        w = float(text)
    except ValueError:
        w = float("nan")
    if not (math.isfinite(w) and w >= 0):
        raise ValueError(f"--weave-weight must be 'auto' or a number >= 0, got {text!r}")
    return w


def _weave_weight_arg(text: str) -> float | str:
    try:
        return parse_weave_weight(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--weave-weight ")) from None


def _speeds(text: str | None):
    return None if text is None else [float(x) for x in parse_range(text, "--speeds", 0.0)]


def _fit_files(data: str | None, obj: dict, decays: str) -> list[Path]:
    """The logs a fit used (and eigen/segments.csv for listed decays): its provenance."""
    from bikeid.dataset.sbw_logs import data_dir, find_logs

    files = [p for p in find_logs(data_dir(data)) if p.name in set(obj["fit_files"])]
    if decays == "listed":  # dataset.decays reads the segments.csv beside each log
        segments = sorted({p.parent / "segments.csv" for p in files})
        files += [s for s in segments if s.is_file()]
    return files


def _log_files(report: dict, obj: dict) -> list[Path]:
    """The logs a fit used (and the segments.csv beside them): its provenance."""
    used = set(obj["fit_files"])
    return [Path(p) for p in report["read"]
            if Path(p).name in used or Path(p).name == "segments.csv"]  # fmt: skip


def add_effects_file_option(p: argparse.ArgumentParser, role: str) -> None:
    """``--effects-file FILE``: a user's effect declarations (:mod:`bikeid.sim.effect_files`)."""
    p.add_argument(
        "--effects-file", metavar="FILE",
        help=f"YAML/JSON file declaring extra effects in the law language (e.g. law: 'roll: "
        f"-c * phidot'; bikeid.sim.effect_files), {role}",
    )  # fmt: skip


def use_effects_file(args: argparse.Namespace) -> tuple[str, ...]:
    """Register the effects of ``--effects-file`` (none without it); their names.

    Raises
    ------
    InputError
        One line naming the file's line and the fix.
    """
    if not getattr(args, "effects_file", None):
        return ()
    from bikeid.dataset.files import check_input_file
    from bikeid.sim.effect_files import load_effects_file

    check_input_file(args.effects_file, "--effects-file")
    return load_effects_file(args.effects_file).names


def cmd_fit(args) -> int:
    import sys

    from bikeid.dataset.decays import MIN_FIT_DECAYS
    from bikeid.ident.effects.pipeline import evaluate_json, fit_model, save_fit

    ww = parse_weave_weight(str(args.weave_weight))
    _check_model_output(args)  # before minutes of fitting
    user = use_effects_file(args)
    ws, base, law, report = load_log_decays(args, _speeds(args.speeds),
                                            min_decays=MIN_FIT_DECAYS)  # fmt: skip
    bar = terminal_progress("measured fit", unit="fit", quiet=args.quiet)
    rule = acceptance_rule(args)
    out = fit_model(ws, args.max_effects, args.plant, args.stability, ww, progress=bar, rule=rule,
                    model=base, law=law)  # fmt: skip
    out["decays"] = args.decays if args.format == "sbw" else "detected"
    out["experiment"]["bicycle"] = args.bicycle or "steer-by-wire"
    out["experiment"]["input"] = ws[0].drive
    out["decay_report"] = report
    settings = {"max_effects": args.max_effects, "stability": args.stability,
                "weave_weight": ww, "speeds": _speeds(args.speeds), "format": args.format,
                **to_jsonable(rule.as_dict())}  # fmt: skip
    if args.format != "sbw":
        settings.update(columns=args.columns, units=args.units, time=args.time, flip=args.flip)
    save_fit(out, args.out, settings, _log_files(report, out))
    if not args.quiet:  # the file written, also when stderr is not a terminal
        print(f"measured fit: wrote {args.out}", file=sys.stderr, flush=True)
    for note in out["notes"]:
        print(f"note: {note}")
    print(f"decays: {len(ws)} at the fit speeds, of {sum(f['kept'] for f in report['files'])} "
          f"usable in {len(report['files'])} log(s); "
          f"{sum(len(f['rejected']) for f in report['files'])} detected pushes rejected "
          f"(decay_report in the model file); {len(out['dropped_windows'])} dropped; input "
          f"{ws[0].drive}")  # fmt: skip
    ch = out["plant_choice"]
    print(f"nominal plant: {out['plant']} ({ch['reason']})")
    if ch["asked"] != "auto":
        print(f"note: the {out['plant']} plant was forced and not compared with the other; a "
              "mismatch of the nominal plant can be read as an effect (--plant auto compares "
              "both plants' final models)")  # fmt: skip
    pc = out.get("plant_check")
    if pc:  # --plant auto: both selections, compared
        print(f"plant check: the selections with the two plants "
              f"{'agree' if pc['agree'] else 'disagree'} (up to their ambiguity sets): linear "
              f"{pc['linear']['verdict']}, nonlinear {pc['nonlinear']['verdict']}")  # fmt: skip
    verdict = out["identification"]["verdict"] or ("nothing: no effect, and no structure beyond "
                                                   "the instruments' floor")
    print(f"verdict: {verdict}; effects {out['effects']}")
    if user:  # the user's effects, marked
        from bikeid.ident.effects.library import LIBRARY

        cands = [n for n in user if n in LIBRARY]
        chosen = [n for n in cands if n in out["effects"]]
        print(f"user effects from {args.effects_file}: candidates {', '.join(cands) or 'none'}"
              f"; selected {', '.join(chosen) or 'none'}")  # fmt: skip
    from bikeid.ident.effects.selection import evidence_lines

    uncertain = bool(ch.get("uncertain"))  # the chosen plant's evidence names no effect
    for line in [] if uncertain else evidence_lines(out["identification"]["evidence"]):
        print(f"  {line}")
    w = out["identification"]["weave_weight"]
    if ww == "auto" and w == 0 and law is not None:  # (no law: a note above says why)
        print("weave term off: no fit speed has >= 3 decays with a measurable weave")
    if "selection_frequency" in out:
        freq = ", ".join(f"{k} {v:.2f}" for k, v in out["selection_frequency"].items())
        print(f"selected in {args.stability} subsamples (fraction): {freq}")
    if out["effects"]:  # the selection's own held-out half (every second decay), with interval
        from bikeid.ident.effects.before_after import verdict_text

        kept = {(w["file"], w["start"]) for w in out["fit_windows"]}
        held = [w for w in ws if (w.file, w.start) in kept][1::2]
        s = evaluate_json(out, held)["summary"]
        print(f"held-out half of the fit decays ({len(held)}; used by the selection, so not "
              f"out of sample): {verdict_text(s)}")  # fmt: skip
    return 0


def _print_file_errors(out: dict) -> None:
    for f in out["files"]:
        print(f"{f['file']:40s} v={f['speed']:.2f}  before {f['error_before']:.3f}  "
              f"after {f['error_after']:.3f}")  # fmt: skip


def cmd_evaluate(args) -> int:
    from bikeid.dataset.decays import load_decays
    from bikeid.dataset.files import check_input_file
    from bikeid.ident.effects.pipeline import (
        evaluate_json,
        evaluate_plant_model,
        model_from_json,
        plant_model_file,
    )

    check_input_file(args.model, "--model")  # /dev/zero or a FIFO would never end
    use_effects_file(args)
    plant_model = plant_model_file(args.model)
    if plant_model is not None:  # an identified plant model (bikeid identify --out)
        if args.format != "sbw":
            raise InputError("an identified plant model is evaluated on the steer-by-wire "
                             "logs (--format sbw); on your logs evaluate a 'measured fit' "
                             "model")  # fmt: skip
        if args.input != "logged":
            raise InputError(
                f"{args.model} holds an identified plant model, which knows no controller: "
                "evaluate it with --drive logged (the logged steer command replayed)"
            )
        ws = load_decays(args.data, _speeds(args.speeds), source=args.decays)
        out = evaluate_plant_model(plant_model, ws)
        if args.json:
            print(dump_json(out))
        else:
            _print_file_errors(out)
            s = out["summary"]
            print(f"summary ({s['windows']} windows, logged command replayed): before "
                  f"{s['error_before']:.3f} after {s['error_after']:.3f}; "
                  f"{len(s['skipped'])} windows at other speeds skipped")  # fmt: skip
        return 0
    model, obj = model_from_json(args.model)
    if obj.get("plant_defaulted"):
        print(
            f"bikeid measured evaluate: {args.model} names no plant; using "
            f"{obj['plant']!r}, the plant 'measured fit' used before it recorded one",
            file=sys.stderr,
        )
    sp = _speeds(args.speeds)
    ws, _, _, _ = load_log_decays(
        args, sp, exclude=None if sp else obj.get("fit_speeds"), purpose="the evaluation",
        experiment=obj.get("experiment") or {},
    )  # fmt: skip
    out = evaluate_json(obj, ws)
    if out.get("note"):
        print(f"bikeid measured evaluate: {out['note']}", file=sys.stderr)
    if args.json:
        print(dump_json(out))
    else:
        from bikeid.ident.effects.before_after import verdict_text

        _print_file_errors(out)
        s = out["summary"]
        print(f"summary: before {s['error_before']:.3f} after {s['error_after']:.3f} "
              f"(weave {s['weave_error_before']:.3f} -> {s['weave_error_after']:.3f}; the "
              f"measured weave is uncertain by {s['weave_data_rel_std']:.3f})")  # fmt: skip
        print(f"before/after: {verdict_text(s)}")
        print(f"  ({s['interval']})")
        for when in ("before", "after"):
            a = s[f"push_asymmetry_{when}"]
            print(f"error by push direction {when}: {_asymmetry_text(a)}")
        for f in out["validation"]["files"]:  # the model's validation (bikeid validate's tests)
            print(f"validation {f['file']}: " + "; ".join(
                f"{c} fit {f['fit'][c]:.1f} %, residuals "
                f"{'white' if r['white'] else 'not white'}"
                + ("" if "independent" not in r else
                   f", {'independent of' if r['independent'] else 'correlated with'} T_ext")
                for c, r in f["residuals"].items()))  # fmt: skip
    return 0


def cmd_trials(args) -> int:
    from bikeid.experiments.measured.effect_trials import format_summary, run_trials

    effects = None if not args.effects else tuple(x.strip() for x in args.effects.split(","))

    bar = terminal_progress("trials", json_output=args.json, unit="trial")
    finished = []
    if bar:
        bar(0, args.n, "")

    def progress(row):
        if args.log:
            with open(args.log, "a") as fh:
                fh.write(json.dumps(to_jsonable(row)) + "\n")
        finished.append(row)
        if bar:
            bar(len(finished), args.n, "")

    out = run_trials(
        args.n, args.seed, args.processes, effects, nonlinear=not args.linear, progress=progress,
        dask=args.dask,
        rule=acceptance_rule(args),
    )  # fmt: skip
    if args.json:
        print(dump_json(out))
        return 0
    s = out["summary"]
    print(format_summary(s))
    print(f"{s['trials']} trials, {s['wall_seconds']:.0f} s wall, {s['processes']} processes")
    return 0


def _check_model_output(args) -> None:
    """``measured fit --out``: a regular file that is none of the inputs (before the fit)."""
    from bikeid.dataset.files import check_output_path, check_outputs

    check_output_path(args.out)
    check_outputs([args.out], [*(getattr(args, "file", None) or []), args.data])


def _owned_output(args, command: str, inputs: list):
    """The ``--out`` folder of report/study: none of the inputs in it, owned by ``command``
    (:func:`bikeid.dataset.files.owned_folder`); checked before any work."""
    from bikeid.dataset.files import check_outputs, check_owned_folder, owned_folder

    check_owned_folder(args.out, command)
    check_outputs([args.out], inputs)
    return owned_folder(args.out, command)


def cmd_report(args) -> int:
    from bikeid.dataset.sbw_logs import data_dir
    from bikeid.experiments.measured.report import write_report

    if args.model:  # refuse a bad model, then a missing data folder, before making the folder
        from bikeid.dataset.files import check_input_file

        check_input_file(args.model, "--model")  # /dev/zero or a FIFO would never end
        from bikeid.ident.effects.pipeline import model_from_json

        model_from_json(args.model)
    data = data_dir(args.data)
    with _owned_output(args, "bikeid measured report", [data, args.model]):
        path = write_report(args.out, args.data, args.model)
    print(path)
    return 0


def cmd_study(args) -> int:
    from bikeid.dataset.files import check_output_path
    from bikeid.dataset.sbw_logs import data_dir
    from bikeid.experiments.measured.study import run_study
    from bikeid.experiments.measured.study_plots import headline, write_study

    data_dir(args.data)
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise InputError(f"--out {args.out} is not a folder; give a folder (created if missing) "
                         "for report.md, study.json and the figures")  # fmt: skip
    check_output_path(Path(args.out) / "report.md")
    say = None if args.json else (lambda t: print(f"fitting: {t}", file=sys.stderr))
    with _owned_output(args, "bikeid measured study", [data_dir(args.data)]):
        study = run_study(args.data, fit_effects=args.fit_effects, quick=args.quick,
                          progress=say)  # fmt: skip
        path = write_study(study, args.out)
    if args.json:
        print(dump_json({**{k: v for k, v in study.items() if k != "_models"},
                         "headline": headline(study)}))  # fmt: skip
        return 0
    for tag, h in headline(study).items():
        print(f"fit {tag} m/s: best on held-out decays {h['best']} "
              f"({h['ratio_to_whipple']:.2f} x Whipple's median decay error)")  # fmt: skip
    print(path)
    return 0


def _asymmetry_text(a: dict) -> str:
    """Push-direction errors, saying "no pushes" where a side has none (never "nan")."""
    import math

    def num(x, fmt):
        return format(x, fmt) if x is not None and math.isfinite(x) else "n/a"

    if not all(a.get(k) is not None and math.isfinite(a[k]) for k in ("error_right", "error_left")):
        return (f"right {num(a.get('error_right'), '.3f')}, left {num(a.get('error_left'), '.3f')}"
                " (no comparison: one direction has no pushes)")  # fmt: skip
    return (f"right {a['error_right']:.3f}, left {a['error_left']:.3f} (ratio "
            f"{num(a.get('ratio'), '.2f')}, p = {num(a.get('p_value'), '.3g')})")  # fmt: skip


def cmd_fetch(args) -> int:
    from bikeid.dataset.download import CAMPAIGN, PINNED, fetch

    sums = fetch(args.dest, files=PINNED | CAMPAIGN if args.all_speeds else PINNED)
    print(f"fetched {len(sums)} files into {Path(args.dest) / 'tudelft-sbw'}")
    return 0


#: ``--format`` of ``measured fit|evaluate``: the steer-by-wire logs or your own.
LOG_FORMATS = {
    "sbw": "TU Delft steer-by-wire logs: --data FOLDER (default $BIKEID_DATA) or log files; "
    "listed or detected decays (--decays)",
    "csv": "your own CSV logs, read with --columns as bikeid identify reads them; decays "
    "detected from the roll rate",
    "hdf5": "your own HDF5 logs, read with --columns as bikeid identify reads them",
}
INPUT_HELP = (
    "what drives the model over each window: 'loop' the known controller law closed around "
    "the model (the steer-by-wire logs' steer-into-lean law, or --controller); 'kstep' the "
    "logged steer torque through the model's Kalman filter, each output predicted one weave "
    "period ahead (no controller needed, the error stays bounded where the bicycle is "
    "unstable); 'logged' the logged steer torque replayed open loop (unstable models grow). "
    "Default: loop for the steer-by-wire logs and with --controller, else kstep"
)


def add_log_options(p: argparse.ArgumentParser) -> None:
    """The data options of ``measured fit|evaluate``: ``bikeid identify``'s, and the experiment.

    FILE... with ``--format csv|hdf5`` and ``--columns``, ``--units``, ``--time``, ``--flip``
    and the time-window and speed-splitting options of
    :func:`bikeid.experiments.cli.log_options.add_data_options` (the same reader), or the
    steer-by-wire folder (``--format sbw``, the default, ``--data``); plus ``--bicycle`` (the
    nominal parameters), ``--controller``/``--gains`` (a known law) and ``--drive``.

    Parameters
    ----------
    p : argparse.ArgumentParser
        The subcommand's parser.

    Returns
    -------
    None
    """
    from bikeid.experiments.cli.log_options import add_data_options

    add_data_options(p, LOG_FORMATS, None, files="*")
    p.add_argument(
        "--bicycle", default=None, metavar="NAME|FILE",
        help="nominal bicycle parameters: a name (see bikeid eig -h) or a .yaml/.json file "
        "(default: steer-by-wire for --format sbw; required for your own logs)",
    )  # fmt: skip
    p.add_argument(
        "--controller", choices=("steer-into-lean",), default=None,
        help="the logs' controller law, T = K (V - v) phidot, with --gains (default: none for "
        "your own logs: the model is scored by its k-step prediction error; the steer-by-wire "
        "logs' law K=2, V=6.5 for --format sbw)",
    )  # fmt: skip
    p.add_argument(
        "--gains", type=mapping_arg("--gains"), default=None, metavar="K=..,V=..",
        help="the law's parameters: K [N s^2/rad] and V [m/s] (default K=2,V=6.5)",
    )  # fmt: skip
    p.add_argument(
        "--drive", dest="input", choices=("loop", "kstep", "logged"), default=None, help=INPUT_HELP
    )


def _law(args: argparse.Namespace):
    """The :class:`~bikeid.ident.effects.log_decays.ControlLaw` of ``--controller``/``--gains``
    (None: not given)."""
    from bikeid.ident.effects.log_decays import ControlLaw

    gains = dict(args.gains or {})
    if gains and args.controller is None and args.format != "sbw":
        raise InputError("--gains needs --controller steer-into-lean (the law they belong to)")
    bad = sorted(set(gains) - {"K", "V"})
    if bad:
        raise InputError(f"--gains {','.join(bad)}: the steer-into-lean law has K [N s^2/rad] "
                         "and V [m/s]; give --gains K=2,V=6.5")  # fmt: skip
    if args.controller is None and not gains:
        return None  # the steer-by-wire logs' own law, or the model file's
    try:
        k, v = float(gains.get("K", 2.0)), float(gains.get("V", 6.5))
    except ValueError:
        raise InputError(f"--gains {gains}: K and V must be numbers") from None
    return ControlLaw(args.controller or "steer-into-lean", k, v)


def load_log_decays(
    args: argparse.Namespace,
    speeds: list[float] | None = None,
    exclude: list[float] | None = None,
    min_decays: int = 1,
    purpose: str = "the fit",
    experiment: dict | None = None,
) -> tuple[list, object, str | None, dict]:  # fmt: skip
    """:func:`bikeid.ident.effects.log_decays.decays_from_logs` of the parsed options.

    Returns the windows, the nominal experiment, the law's name (None: none known) and the
    decay report.
    """
    from bikeid.experiments.cli.log_options import log_options
    from bikeid.ident.effects.log_decays import decays_from_logs

    options = log_options(args, bicycle=args.bicycle, input="T_delta")
    windows, model, law, report = decays_from_logs(
        list(args.file or []), options, _law(args), decays=args.decays, data=args.data,
        drive=args.input, speeds=speeds, exclude=exclude, min_decays=min_decays,
        purpose=purpose, experiment=experiment,
    )  # fmt: skip
    return windows, model, (law.name if law else None), report
