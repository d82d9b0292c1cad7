"""``bikeid identify``: direct (Moore & Hubbard), canonical PEM (Chen & Dao) or grey-box PEM.

For simulated runs (``meta['parameters']`` present) the true linearization is
printed beside the estimate (``true_eigenvalues``).
"""

from __future__ import annotations

import argparse

from bikeid.controllers.registry import STUDY_CONTROLLERS
from bikeid.experiments.cli.args import (
    MAX_WORKERS,
    check_figure_path,
    dump_json,
    integer,
    number,
    range_text,
)
from bikeid.experiments.cli.log_options import FORMATS, add_data_options, log_options
from bikeid.experiments.parallel import DASK_HELP
from bikeid.experiments.progress import quiet, stage_lines, terminal_progress
from bikeid.experiments.testbed.method_choices import MethodChoices


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "identify",
        formatter_class=DefaultsFormatter,
        help="identify the bicycle from runs: bikeid HDF5 files or your own CSV/HDF5 logs",
        description=(
            "Identify from bikeid run files (the default format) or from your own logs: "
            "--format csv|hdf5 with --columns mapping bikeid signals (phi, delta, phidot, "
            "deltadot, T_delta, and v unless --speed is given) to your columns or datasets, "
            "--units for non-SI columns (deg, deg/s, km/h, N cm, ms), --flip for signals "
            "logged positive to the left. Each log file becomes one run; a log whose speed "
            "varies is split into constant-speed stretches, and runs whose mean speeds lie "
            "within --speed-tolerance pool into one model at their weighted mean speed. "
            "Before any fit the sample period, each rate against its angle's derivative and "
            "the input's excitation are checked (--skip-check, --no-checks)."
        ),
    )
    add_data_options(
        p,
        FORMATS,
        input_help="the runs' torque signal [N m] used as the model's steer-torque input "
        "(default T_delta; e.g. sil_command of the steer-by-wire logs)",
    )  # fmt: skip
    p.add_argument(
        "--method", choices=MethodChoices(presets=False), default="pem", metavar="METHOD",
        help="one of %(choices)s (the table ident.methods.METHODS). pem: canonical "
        "prediction-error model per speed (Chen & Dao); greybox: PEM of chosen matrix entries "
        "over all speeds; direct: least squares of the equations of motion (Moore & Hubbard; "
        "biased on stiff loops, README)",
    )  # fmt: skip
    p.add_argument(
        "--free", default=None, metavar="NAME,...",
        help="greybox/direct: free matrix entries, e.g. Mpd,K0pd,Mdd,K0dd,K2dd (default Moore "
        "& Hubbard's set, ident.greybox.DEFAULT_FREE / ident.direct.MOORE_ROLL, MOORE_STEER); "
        "the rest fixed at --bicycle's values",
    )  # fmt: skip
    p.add_argument(
        "--drop-unidentifiable", action="store_true",
        help="greybox: fix the worst-determined free entries until the condition number is "
        "below ident.greybox.MAX_CONDITION (default: refuse, exit 4)",
    )  # fmt: skip
    p.add_argument(
        "--noise-model", choices=("free", "kalman", "gain", "none"), default=None,
        help="pem: the one-step predictor's innovation gain: free (default: estimated as the "
        "Kalman gain of fitted noise covariances, a predictor stable by construction), "
        "kalman (the same, named), gain (free entries; may end on the predictor's stability "
        "boundary, where intervals are withheld), none (output error: biased in closed loop, "
        "refused where the plant is open-loop unstable)",
    )  # fmt: skip
    p.add_argument(
        "--speed-parameterized",
        action="store_true",
        help="pem: one model over all speeds (odd a's = alpha + beta v^2, even a's = gamma v)",
    )
    p.add_argument(
        "--bicycle", help="fixed-entry values for direct/greybox, and the nominal bicycle of "
        "--plot (default: the runs' meta)"
    )  # fmt: skip
    p.add_argument("--iv", action="store_true", help="direct: instrumental variables (lagged)")
    p.add_argument(
        "--derivative", choices=("interval", "central", "forward", "backward"),
        default="interval",
        help="direct: how accelerations are formed (see ident.signals). 'interval' (default): "
        "the equation averaged over each sample interval, exact for zero-order-held torques; "
        "Moore & Hubbard's recipe is '--derivative central --cutoff 15', which is biased by "
        "the torque steps of a sampled controller (docs/accuracy.md)",
    )  # fmt: skip
    p.add_argument(
        "--cutoff", type=number(0.0, 1e4, unit="Hz"), default=None,
        help="direct: zero-phase low-pass [Hz], 0 = none (default 3 Hz with 'interval', "
        "else 15 Hz as Moore & Hubbard)",
    )  # fmt: skip
    p.add_argument(
        "--outputs", default=None, metavar="NAME,...",
        help="measured states fitted (pem: phi and delta plus optionally phidot, deltadot; "
        "default all four). direct needs all four (its regressors use every state)",
    )  # fmt: skip
    p.add_argument(
        "--out", default=None, metavar="MODEL.json",
        help="save the identified model (ident.model_file: parameters, covariance, data file "
        "hashes, settings; any --method); per-speed pem over several speeds writes "
        "MODEL-v<speed>.json",
    )  # fmt: skip
    p.add_argument(
        "--plot", default=None, metavar="FILE",
        help="draw the identified eigenvalues with their 95 %% intervals against the nominal "
        "bicycle's (--bicycle, else the runs' bicycle, else benchmark) in the complex plane "
        "and, for several speeds or a model over speed, against speed; the format follows "
        "the suffix (.png, .pdf, .svg, .eps, .ps)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print JSON (no progress lines)")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(func=cmd_identify)

    e = sub.add_parser(
        "export",
        help="write runs of a bikeid HDF5 file (or steer-by-wire logs) as CSV (units in the "
        "header)",
        description=(
            "One CSV per run: line 1 the run's metadata as JSON after '# bikeid run: ', line "
            "2 the headers 'name [unit]', then one row per sample (17 significant digits, "
            "exact for float64). Read back with pandas.read_csv(path, comment='#') or "
            "bikeid identify --format csv. With --format sbw, FILE is a steer-by-wire log "
            "or a folder of them (each log one run: its settled stretch, bikeid signals)."
        ),
    )
    e.add_argument("file", help="bikeid HDF5 run file, or (--format sbw) logs or a folder")
    e.add_argument(
        "--format", choices=("bikeid", "sbw"), default="bikeid",
        help="bikeid: a run file written by bikeid; sbw: the steer-by-wire logs",
    )  # fmt: skip
    e.add_argument("--run", default=None, help="run name (default: every run)")
    e.add_argument(
        "--out", required=True,
        help="CSV file (one run) or folder (one RUN.csv per run; created if missing)",
    )  # fmt: skip
    e.set_defaults(func=cmd_export)

    a = sub.add_parser(
        "accuracy",
        help="identification accuracy on the nonlinear closed-loop testbed",
        description=(
            "Simulate 50 s of closed-loop data per speed and controller (cached in DIR/data), "
            "identify with the direct, PEM and grey-box methods and compare eigenvalues, v_w, "
            "v_c and the RHP zero of delta/T_delta with the true linearization. Writes "
            "DIR/accuracy.json and DIR/accuracy.md; progress on stderr when it is a terminal."
        ),
    )
    a.add_argument(
        "--quick",
        action="store_true",
        help="speeds 2, 5, 10 m/s (below v_w, between v_w and v_c, above v_c)",
    )
    a.add_argument(
        "--controllers",
        type=_names_arg(STUDY_CONTROLLERS, "controllers"),
        default=",".join(STUDY_CONTROLLERS),
        help=f"comma-separated subset of {','.join(STUDY_CONTROLLERS)} (default all)",
    )
    rows = a.add_argument(
        "--methods",
        type=_names_arg(ACCURACY_METHODS, "methods"),
        default=None,
        metavar="NAME,...",
        help="comma-separated subset of %(rows)s (default all: every method and preset of "
        "ident.methods; direct: instrumental variables, direct_ls: Moore & Hubbard's least "
        "squares)",
    )
    rows.rows = ACCURACY_METHODS  # type: ignore[attr-defined]  # read by the help text
    a.add_argument(
        "--seeds",
        type=integer(1, 100),
        default=1,
        help="seeds 0..N-1 of the simulated data; with N > 1 the table gives each row's pass "
        "count per seed with its mean and spread (default 1)",
    )
    a.add_argument(
        "--speeds",
        type=range_text("--speeds", 0.1),
        default=None,
        metavar="A:B:STEP",
        help="speeds [m/s] (default 1:15:0.5; stop included)",
    )
    a.add_argument(
        "--workers",
        type=integer(1, MAX_WORKERS),
        default=2,
        help="simulation processes (default 2)",
    )
    a.add_argument("--dask", metavar="ADDRESS", help=DASK_HELP)
    a.add_argument("--out", default="accuracy", metavar="DIR", help="output folder")
    a.add_argument("--json", action="store_true", help="print JSON instead of the table")
    a.set_defaults(func=cmd_accuracy)  # fmt: skip


class DefaultsFormatter(argparse.HelpFormatter):
    """Help text that states each option's default unless the text already names it."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if (not action.option_strings or "default" in text
                or action.default in (None, False, argparse.SUPPRESS)):  # fmt: skip
            return action.help
        return f"{text} (default: %(default)s)"


#: The rows of ``bikeid accuracy``: every name of the method table
#: (``ident.methods.names()``, read on first use so that ``--help`` does not import it).
ACCURACY_METHODS = MethodChoices()

def _truth(runs):
    """The simulated bicycle: ``meta['parameters']`` or ``meta['bicycle']['parameters']``
    (closed-loop runs and sweeps); None for measured data."""
    from bikeid.sim.parameters import from_mapping

    meta = runs[0].meta
    bicycle = meta.get("bicycle")  # a name (measured logs) or the simulated bicycle
    values = meta.get("parameters") or (bicycle if isinstance(bicycle, dict) else {}).get(
        "parameters"
    )
    return from_mapping(values, name="run meta") if values else None


def _sorted(z):
    import numpy as np

    return sorted(np.asarray(z, dtype=complex), key=lambda c: (c.real, c.imag))


def cmd_export(args: argparse.Namespace) -> int:
    from contextlib import nullcontext
    from pathlib import Path

    from bikeid.dataset.files import (
        check_output_path,
        check_outputs,
        check_owned_folder,
        owned_folder,
    )
    from bikeid.dataset.store import export_csv, list_runs, read_run

    if args.format == "sbw":
        from bikeid.dataset.sbw_logs import load_log, settled

        if args.run is not None:
            raise ValueError("--run applies to bikeid run files; give the log file itself")
        from bikeid.dataset.logs import LogOptions, data_files

        found = data_files([args.file], LogOptions(format="sbw"))
        logs = {Path(f).name.removesuffix(".gz").removesuffix(".log"): f for f in found}
        names = list(logs)
    else:
        names = [args.run] if args.run else list_runs(args.file)
    if not names:
        raise ValueError(f"{args.file} holds no runs")
    out = Path(args.out)
    if out.suffix.lower() == ".csv":
        if len(names) != 1:
            raise ValueError(
                f"{args.file} holds {len(names)} runs: give --run NAME, or a folder as --out"
            )
        targets = {names[0]: out}
    else:
        if out.exists() and not out.is_dir():
            raise ValueError(f"--out {out} is a file: give a .csv name or a folder")
        targets = {n: out / f"{n}.csv" for n in names}
    for target in targets.values():
        check_output_path(target)  # refuse a link or device before writing anything
    folder = None if out.suffix.lower() == ".csv" else out
    owned = [t.name for t in targets.values()]
    if folder is not None:  # files of the user's of the same names are refused, by name
        check_owned_folder(folder, "bikeid export", names=owned)
    inputs = list(logs.values()) if args.format == "sbw" else [args.file]
    check_outputs([folder, *targets.values()], inputs)
    if args.format == "sbw":  # all readable before the first write
        runs = {n: settled(load_log(f)) for n, f in logs.items()}
    else:
        runs = {n: read_run(args.file, n) for n in names}
    with owned_folder(folder, "bikeid export", names=owned) if folder else nullcontext():
        for n, target in targets.items():
            export_csv(runs[n], target)
            print(target)
    return 0


def _outputs(text: str | None, method: str) -> tuple[str, ...] | None:
    """``--outputs``: the measured states fitted (None: the method's default)."""
    from bikeid.sim.conventions import CANONICAL_STATE
    from bikeid.sim.errors import InputError

    if text is None:
        return None
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names or len(set(names)) != len(names) or not set(names) <= set(CANONICAL_STATE):
        raise InputError(
            f"--outputs {text!r}: give measured states from {','.join(CANONICAL_STATE)}, "
            "comma-separated, without repeats"
        )
    if method == "direct" and set(names) != set(CANONICAL_STATE):
        raise InputError(
            f"--outputs {text!r}: direct least squares needs phi, delta, phidot and deltadot "
            "(its regressors use every state and both accelerations); drop --outputs or use "
            "--method pem"
        )
    if not {"phi", "delta"} <= set(names):
        raise InputError(
            f"--outputs {text!r}: the canonical model needs phi and delta among its outputs "
            "(Chen & Dao's output matrix); add them"
        )
    return names


def _model_targets(out: str, speeds: list[float], per_speed: bool) -> list:
    """``--out`` file(s): one, or one per speed for per-speed pem over several speeds."""
    from pathlib import Path

    from bikeid.dataset.files import check_output_path

    path = check_output_path(Path(out))
    if per_speed and len(speeds) > 1:
        targets = [path.with_name(f"{path.stem}-v{v:g}{path.suffix or '.json'}") for v in speeds]
    else:
        targets = [path]
    for t in targets:
        check_output_path(t)  # refuse a link or folder before the (long) fit
    return targets


def _settings(args: argparse.Namespace) -> dict:
    """The method, its settings (ident.methods) and the data options saved with the model."""
    s: dict = {"command": "bikeid identify", "method": args.method,
               **log_options(args).settings()}  # fmt: skip
    method, run_settings = _method_settings(args)
    s.update(run_settings.to_json())
    if method.fixed_entries:
        s.update(bicycle=args.bicycle)
    if method.free_entries:
        s.update(free=args.free)
    return s


def cmd_identify(args: argparse.Namespace) -> int:
    import os
    import sys

    import numpy as np

    from bikeid.dataset.files import check_distinct_inputs, check_output_path, check_outputs
    from bikeid.dataset.logs import IMPORT_FORMATS, load_runs, pool_runs
    from bikeid.dataset.logs import data_files as files_of
    from bikeid.ident.methods import SKIPPED_NOTE, check_informativity
    from bikeid.ident.model_file import file_provenance, save_model
    from bikeid.sim.errors import InputError
    from bikeid.sim.linear import eigenvalues

    outputs = _outputs(args.outputs, args.method)
    options = log_options(args, bicycle=args.bicycle)
    data_files = files_of(args.file, options)  # no output may be an input; none counted twice
    if args.out:
        check_output_path(args.out)  # a folder or link at --out: named as such first
    check_figure_path(args.plot, "--plot")  # the suffix names the figure's format
    check_outputs([args.out, args.plot], [*data_files, args.bicycle])
    check_distinct_inputs(data_files)
    method, run_settings = _method_settings(args)  # ident.methods.METHODS; options checked
    say = stage_lines("identify", json_output=args.json, quiet=args.quiet)
    notes: list[str] = []

    def note(msg: str) -> None:  # never silent: on stderr even with --quiet/--json
        notes.append(msg)
        print(f"note: {msg}", file=sys.stderr, flush=True)

    runs = load_runs(args.file, options, note)
    if not runs:
        raise ValueError(f"{', '.join(args.file)} hold no runs")
    if options.bicycle is None and options.format in IMPORT_FORMATS:
        note("the relative signs of roll, steer and torque are unchecked (no --bicycle): a "
             "mirrored axis leaves the eigenvalues unchanged but flips the coupling signs "
             "(e.g. torque to roll); give --bicycle NAME to check them")  # fmt: skip
    runs = pool_runs(runs, args.speed_tolerance)
    truth = _truth(runs)
    speeds = sorted({round(r.speed, 6) for r in runs})
    free = [n.strip() for n in args.free.split(",") if n.strip()] if args.free else None
    # the library's informativity check, run here before any stage line (a refusal stays
    # one line) and again, cheaply, inside the fit; skipped on request with a note
    skip_informativity = "informativity" in options.skip
    informativity = None if skip_informativity else check_informativity(runs, run_settings,
                                                                        free=free)
    if skip_informativity:
        note(SKIPPED_NOTE)
    # stage lines start once the data passed every check: a refusal stays one line
    say(f"{len(runs)} run(s) from {len(data_files)} file(s) at "
        f"{', '.join(f'{v:g}' for v in speeds)} m/s passed the checks")
    targets, provenance, settings = [], [], {}
    if args.out:
        targets = _model_targets(args.out, speeds, method.one_file_per_speed(run_settings))
        check_outputs(targets, [*data_files, args.bicycle])
        if args.plot is not None and os.path.realpath(args.plot) in map(os.path.realpath,
                                                                         targets):
            raise InputError(f"--plot {args.plot} is also the model file of --out; give the "
                             "figure another name")  # fmt: skip
        provenance = file_provenance(data_files)
        settings = _settings(args)
    out: dict = {"file": list(map(str, args.file)), "method": args.method, "speeds": speeds,
                 "input": args.input, "informativity": informativity}  # fmt: skip
    say(f"fitting ({args.method}: {run_settings.describe()})")
    reference = _reference(args, runs, truth) if method.fixed_entries else None
    bar = terminal_progress("identify", json_output=args.json, unit="fit",
                            quiet=args.quiet)  # fmt: skip
    fitted = method.fit(runs, run_settings, reference=reference, free=free, outputs=outputs,
                        progress=bar, informativity="skip" if skip_informativity
                        else "refuse")  # fmt: skip
    out["settings"] = {"method": args.method, **run_settings.to_json(),
                       "description": run_settings.describe()}  # fmt: skip
    out["outputs"] = list(fitted.outputs)
    out.update(fitted.details)
    saved = list(zip(fitted.models, targets, strict=True)) if targets else []
    eig = {v: fitted.eigenvalues(v) for v in speeds}
    interval_models, speed_model = fitted.interval_models, fitted.speed_model
    structure = None
    if interval_models is not None:  # a fit-quality figure, and data it cannot explain refused
        out["fit_percent"] = _fit_quality(runs, interval_models)
        structure = _structure(runs, interval_models, speed_model, say)
    settings["outputs"] = out["outputs"]  # as fitted (the method's default when not given)
    per_speed = []
    for v in speeds:
        row = {"speed": v, "eigenvalues": eig[v], "modes": list(eig[v].modes)}
        if truth is not None:
            row["true_eigenvalues"] = _sorted(eigenvalues(truth, v))
        per_speed.append(row)
    if interval_models is not None:
        out["intervals"] = _intervals(interval_models, speed_model, structure)
        for row, ei in zip(per_speed, out["intervals"].pop("eigenvalues"), strict=True):
            row["eigenvalue_intervals"] = ei
    out["per_speed"] = per_speed
    results = {"structure_check": structure.to_json()} if structure is not None else None
    for model, target in saved:  # a model over speed with its critical speeds' intervals
        save_model(model, target, provenance=provenance, settings=settings, speeds=speeds,
                   results=results, **_critical_to_save(model, out.get("intervals")))  # fmt: skip
    out["model_files"] = [str(t) for _, t in saved]
    for f in out["model_files"]:
        say(f"wrote {f}")
    if notes:
        out["notes"] = notes
    if args.plot is not None:
        from bikeid.experiments.plots import plot_identified_eigenvalues

        name, nominal = _nominal(args, runs, truth)
        out["plot"] = str(plot_identified_eigenvalues(
            per_speed, nominal, args.plot, nominal_label=name, speed_model=speed_model,
            title=f"{', '.join(map(str, args.file))}: method {args.method}"))  # fmt: skip
        say(f"wrote {out['plot']}")
    if truth is not None and args.method == "pem" and args.speed_parameterized:
        from bikeid.sim.linear import critical_speeds

        out["true_critical_speeds"] = critical_speeds(truth)
    if args.json:
        print(dump_json(out))
        return 0
    np.set_printoptions(precision=5, suppress=True, linewidth=110)
    print(f"{', '.join(args.file)}: {len(runs)} runs, method {args.method}")
    print(f"settings: {run_settings.describe()}")
    for v, q in out.get("fit_percent", {}).items():
        print(f"one-step prediction fit at {v:g} m/s [%] (MATLAB compare): "
              + ", ".join(f"{k} {x:.1f}" for k, x in q.items()))  # fmt: skip
    for line in _detail_lines(out):
        print(line)
    for f in out["model_files"]:
        print(f"model saved to {f}")
    if "plot" in out:
        print(f"eigenvalue figure saved to {out['plot']}")
    for row in per_speed:
        fmt = "  ".join(f"{z.real:+.3f}{z.imag:+.3f}j" for z in row["eigenvalues"])
        print(f"v={row['speed']:6.2f}  identified {fmt}")
        if row.get("eigenvalue_intervals"):
            for part in ("real", "imag"):
                print(f"{'':8s}  95 % {part[:2].capitalize()}  "
                      f"{_interval_cells(row['eigenvalue_intervals'], part)}")  # fmt: skip
        if "true_eigenvalues" in row:
            fmt = "  ".join(f"{z.real:+.3f}{z.imag:+.3f}j" for z in row["true_eigenvalues"])
            print(f"{'':8s}  true       {fmt}")
    if out.get("critical_speeds"):  # a model over speed: its answers, intervals or why not
        for line in _critical_lines(out["critical_speeds"], out.get("intervals"), speeds):
            print(line)
    if "intervals" in out:
        for line in _interval_lines(out["intervals"]):
            print(line)
    return 0


#: Least one-step prediction fit [%] (100 (1 - ||y - yhat|| / ||y - mean y||)) the best
#: output must reach at every speed: a model of pure noise scores 0-1 %, the testbed's runs
#: 80-96 %, five steer-by-wire logs fitted alone 77-99.8 % (per output, docs/robustness.md).
MIN_FIT_PERCENT = 5.0


def _fit_quality(runs: list, models: dict) -> dict:
    """One-step prediction fit [%] per speed and output; refuse a speed nothing explains.

    Raises UntrustworthyResult (exit 4) when, at some speed, every output's fit is below
    :data:`MIN_FIT_PERCENT`: the model predicts the data no better than their mean.
    """
    from bikeid.ident.validate import compare
    from bikeid.sim.errors import UntrustworthyResult

    quality: dict = {}
    for v, model in models.items():
        at_v = [r for r in runs if round(r.speed, 6) == v]
        try:
            fit = compare(at_v, model, horizon=1).fit
        except (ValueError, ArithmeticError):  # no figure (e.g. an unstable predictor)
            continue
        quality[v] = {k: float(x) for k, x in fit.items()}
        best = max(quality[v].values())
        if not best >= MIN_FIT_PERCENT:
            raise UntrustworthyResult(
                f"the model explains none of the data at {v:g} m/s: best one-step prediction "
                f"fit {best:.1f} % (below {MIN_FIT_PERCENT:g} %; a model of pure noise scores "
                "about 0 %); check the --columns mapping and that the runs hold the bicycle's "
                "response to its steer torque"
            )
    return quality


def _method_settings(args: argparse.Namespace):
    """The table entry of ``--method`` and its settings from the options (ident.methods)."""
    from bikeid.ident.methods import method

    m = method(args.method)
    if args.free and not m.free_entries:
        raise ValueError("--free applies to --method greybox or direct")
    if args.drop_unidentifiable and args.method != "greybox":
        raise ValueError("--drop-unidentifiable applies to --method greybox")
    if args.speed_parameterized and args.method != "pem":
        raise ValueError(f"--speed-parameterized applies to --method pem ({args.method} is "
                         "always one model over all speeds)")  # fmt: skip
    if args.iv and args.method != "direct":
        raise ValueError("--iv applies to --method direct")
    if args.noise_model and args.method != "pem":
        raise ValueError(f"--noise-model applies to --method pem ({args.method} estimates "
                         "its own innovation gain)")  # fmt: skip
    return m, m.settings(vars(args))


def _reference(args: argparse.Namespace, runs: list, truth):
    """Values of the fixed matrix entries: --bicycle, the logs' bicycle name, or the truth."""
    from bikeid.sim.parameters import by_name

    bicycle = args.bicycle or (runs[0].meta.get("bicycle") if truth is None else None)
    reference = by_name(bicycle) if isinstance(bicycle, str) else truth
    if reference is None:
        raise ValueError("runs carry no parameters: give --bicycle for the fixed entries")
    return reference


def _nominal(args: argparse.Namespace, runs: list, truth) -> tuple:
    """Name and parameters of the nominal bicycle of --plot: --bicycle, the runs' simulated
    bicycle, the logs' bicycle name, else the benchmark bicycle."""
    from bikeid.sim.parameters import benchmark, by_name

    if args.bicycle:
        return args.bicycle, by_name(args.bicycle)
    if truth is not None:
        return "the runs' simulated bicycle", truth
    name = runs[0].meta.get("bicycle")
    if isinstance(name, str):
        return name, by_name(name)
    return "benchmark", benchmark()


def _detail_lines(out: dict) -> list[str]:
    """The method's numbers as text: matrices, free entries with standard errors, fits."""
    import numpy as np

    lines = []
    if "M" in out:
        lines += [f"{k} =\n{out[k]}" for k in ("M", "C1", "K0", "K2", "H")]
    for k, d in out.get("free", {}).items():
        infl = f" (SE inflation {d['inflation']:.3g})" if "inflation" in d else ""
        lines.append(f"  {k:5s} = {d['value']:+.5g} +- {d['stderr']:.2g}{infl}")
    if "least_determined" in out:
        lines.append(f"condition number {out['condition']:.3g} (weakest direction: "
                     f"{', '.join(out['least_determined'])}); fixed as poorly determined: "
                     f"{out['dropped'] or 'none'}")  # fmt: skip
    if "vaf_moore" in out:
        vaf = ", ".join(
            f"{k} {v:.4f}" if isinstance(v, float) and np.isfinite(v) else f"{k} n/a"
            for k, v in out["vaf_moore"].items()
        )
        lines.append(f"VAF (Moore eq. 6): {vaf}; condition: {out['condition']}")
    return lines


def _structure(runs: list, models: dict, speed_model, say):
    """Whether the data reject the structure the intervals assume (ident.structure)."""
    from bikeid.ident.structure import check_structure

    say("testing the model structure (residual tests)")
    return check_structure(runs, models, speed_model=speed_model)


def _intervals(models: dict, speed_model, structure=None) -> dict:
    """95 % eigenvalue intervals per speed and, for a model over speed, of v_w and v_c.

    ``models`` maps each speed to a model with a theta covariance (a CanonicalModel, or a
    model over speed taken there); ``speed_model`` is a SpeedCanonicalModel (the
    speed-parameterized fit, or a grey-box model's :meth:`speed_model`) or None;
    ``structure`` an :class:`~bikeid.ident.structure.StructureCheck`: no intervals at the
    speeds where the data reject the structure, none of v_w, v_c when the model over speed
    is rejected (the estimates stand), the verdict under ``"structure"``.  The reasons go
    to ``"notes"``: a rejected model over speed as two lines (:func:`_withheld_lines`: what
    was rejected, the one fix), the same refusal at several speeds as one line.
    """
    from bikeid.ident.trust import WithheldIntervals
    from bikeid.ident.uncertainty import (
        check_predictor_interior,
        critical_speed_intervals,
        eigenvalue_intervals,
    )
    from bikeid.ident.validation_report import INTERVAL_CALIBRATION
    from bikeid.sim.errors import InputError, UntrustworthyResult

    out: dict = {"level": 0.95, "calibration": INTERVAL_CALIBRATION, "eigenvalues": []}
    notes: list[str] = []
    rejected = set(structure.withheld_speeds) if structure is not None else set()
    over_speed_rejected = bool(speed_model is not None and structure is not None
                               and structure.speed_model_rejected)  # fmt: skip
    if structure is not None:
        out["structure"] = structure.to_json()
        if over_speed_rejected:
            out["withheld"] = _withheld(structure, speed_model)
            notes += [out["withheld"]["what"], f"fix: {out['withheld']['fix']}"]
        else:
            notes.append(structure.note())
    refused: dict[str, list[float]] = {}  # the same refusal at several speeds: one note
    for v, m in models.items():
        try:  # a fit on its predictor's stability boundary has no trustworthy interval
            if round(v, 6) in rejected:  # nor has a structure the data reject: bias
                check_predictor_interior(m)  # (named too when it applies)
                out["eigenvalues"].append(None)
            else:
                out["eigenvalues"].append(eigenvalue_intervals(m, refuse_boundary=True).to_json())
        except (InputError, UntrustworthyResult) as exc:  # the estimate stands, no interval
            out["eigenvalues"].append(None)
            why = exc.cli_message() if isinstance(exc, WithheldIntervals) else str(exc)
            refused.setdefault(why, []).append(v)
    notes += [f"no eigenvalue intervals at {_speed_list(at)}: {why}"
              for why, at in refused.items()]  # fmt: skip
    if over_speed_rejected:
        out["critical_speeds"] = None
        out["critical_speeds_note"] = "withheld: the data reject the model over speed (note)"
    elif speed_model is not None:
        try:
            out["critical_speeds"] = critical_speed_intervals(speed_model).to_json()
        except (InputError, UntrustworthyResult) as exc:  # e.g. a tangential crossing
            out["critical_speeds"] = None
            out["critical_speeds_note"] = (exc.cli_message() if isinstance(exc, WithheldIntervals)
                                           else str(exc))  # fmt: skip
    if notes:
        out["notes"] = notes
    return out


def _speed_list(speeds: list[float]) -> str:
    """``5 m/s``, ``3, 4 m/s`` or, beyond four, ``29 speeds (1-15 m/s)``."""
    if len(speeds) <= 4:
        return ", ".join(f"{v:g}" for v in speeds) + " m/s"
    return f"{len(speeds)} speeds ({min(speeds):g}-{max(speeds):g} m/s)"


def _withheld(structure, speed_model) -> dict:
    """Why a model over speed has no intervals: what was rejected, and the one fix.

    Parameters
    ----------
    structure : ident.structure.StructureCheck
        The verdict, with ``speed_model_rejected`` True.
    speed_model : SpeedCanonicalModel
        The model over speed (its ``per_speed`` fits, if any, decide the fix).

    Returns
    -------
    dict
        ``what`` (one line: the speeds whose tests reject counted against all tested
        speeds, the causes of :meth:`~bikeid.ident.structure.StructureCheck.causes`, what
        is withheld), ``fix`` (the one remedy of :mod:`bikeid.ident.structure` that
        applies: a longer record where a per-speed fit ended on its predictor's stability
        boundary, where neither it nor its intervals can be trusted; else the per-speed
        fit, which these data allow), ``rejected_speeds`` and ``withheld_speeds`` [m/s].
    """
    from bikeid.ident.structure import FIX_LONGER, FIX_PER_SPEED
    from bikeid.ident.uncertainty import PREDICTOR_BOUNDARY_TOL, predictor_radius

    rej, held = list(structure.rejected_speeds), list(structure.withheld_speeds)
    span = ", ".join(f"{v:g}" for v in rej) if len(rej) <= 4 else f"{min(rej):g}-{max(rej):g}"
    what = (f"no 95 % intervals for v_w, v_c or the eigenvalues at any of the {len(held)} "
            f"speeds (the estimates stand): the data reject the model over speed at "
            f"{len(rej)} of {len(held)} speeds ({span} m/s; residual tests, family level "
            f"{structure.level:g}): {structure.causes()}")  # fmt: skip
    radii = [predictor_radius(m) for m in getattr(speed_model, "per_speed", {}).values()]
    boundary = any(r is not None and r > 1.0 - PREDICTOR_BOUNDARY_TOL for r in radii)
    return {"what": what, "fix": FIX_LONGER if boundary else FIX_PER_SPEED,
            "rejected_speeds": rej, "withheld_speeds": held}  # fmt: skip


#: Why a model over speed from a method without intervals (direct) has no critical-speed
#: intervals: they come from a speed-parameterized canonical model (PEM, grey-box).
NO_CRITICAL_INTERVALS = ("this method gives none (critical-speed intervals come from "
                         "--method pem --speed-parameterized or --method greybox)")  # fmt: skip


def _critical_to_save(model, iv: dict | None) -> dict:
    """The critical-speed intervals, or why none, saved with a model over speed."""
    from bikeid.ident.linear_model import SpeedDependentModel

    if not isinstance(model, SpeedDependentModel):
        return {}  # a fixed-speed model has no critical speeds
    if iv is None:
        return {"critical_speeds_note": f"no intervals: {NO_CRITICAL_INTERVALS}"}
    if iv.get("withheld"):
        w = iv["withheld"]
        return {"critical_speeds_note": f"{w['what']}\nfix: {w['fix']}"}
    if iv.get("critical_speeds") is not None:
        return {"critical_speed_intervals": iv["critical_speeds"]}
    return {"critical_speeds_note": iv.get("critical_speeds_note")}


#: What a critical speed is, printed beside it (sim.linear.critical_speeds).
CRITICAL_MEANING = {"v_d": "weave becomes oscillatory", "v_w": "weave speed",
                    "v_c": "capsize speed"}  # fmt: skip


def _critical_lines(crit: dict, iv: dict | None, speeds: list[float]) -> list[str]:
    """v_d, v_w, v_c of a model over speed, each with its 95 % interval or why none.

    ``crit`` is the model's :func:`bikeid.sim.linear.critical_speeds` (searched up to
    30 m/s), ``iv`` the ``intervals`` of :func:`_intervals` (None without a covariance),
    ``speeds`` the fitted speeds [m/s] (a critical speed outside them is extrapolated).
    """
    lo_v, hi_v = min(speeds), max(speeds)
    cells = (iv or {}).get("critical_speeds") or {}
    if iv is None:
        reason = NO_CRITICAL_INTERVALS
    elif iv.get("withheld"):
        reason = "withheld, the data reject the model over speed (note below)"
    else:
        reason = iv.get("critical_speeds_note") or "none computed"
    lines = [f"critical speeds of the model over speed (fitted at {lo_v:g}-{hi_v:g} m/s):"]
    for name, meaning in CRITICAL_MEANING.items():
        v = crit.get(name)
        value = f"{v:.3f} m/s" if v is not None else "none below 30 m/s"
        where = ("" if v is None or lo_v <= v <= hi_v else
                 f"; {'below' if v < lo_v else 'above'} the fitted speeds: "
                 "extrapolated")  # fmt: skip
        c = cells.get(name)
        if name == "v_d":
            why = "no interval (bikeid's intervals cover v_w and v_c)"
        elif c and c.get("interval") is not None:
            lo, hi = c["interval"]
            why = f"95 % interval [{lo:.3f}, {hi:.3f}] m/s" + (
                f" (open: the confidence region holds parameters without {name} in the "
                "searched range)" if c.get("open") else "")  # fmt: skip
        elif c:
            why = "no interval: no parameters in the confidence region have one"
        else:
            why = f"no interval: {reason}"
        lines.append(f"  {name} = {value:>17s}  {meaning}; {why}{where}")
    return lines


def _interval_cells(ei: dict, part: str) -> str:
    """[lower, upper] of the real or imaginary parts, one cell per eigenvalue."""
    return "  ".join(f"[{r[part][0]:+.3f}, {r[part][1]:+.3f}]" for r in ei["eigenvalues"])


def _interval_lines(iv: dict) -> list[str]:
    """The notes of :func:`_intervals` and what the intervals are calibrated on."""
    return [f"note: {n}" for n in iv.get("notes", [])] + [f"note: {iv['calibration']}"]


def _names(text: str, allowed: tuple[str, ...], what: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    bad = [n for n in names if n not in allowed]
    if bad or not names:
        raise ValueError(f"--{what} {text!r}: give a comma-separated subset of {','.join(allowed)}")
    return list(dict.fromkeys(names))


def _names_arg(allowed: tuple[str, ...], what: str):
    def check(text: str) -> str:
        try:
            _names(text, allowed, what)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc).removeprefix(f"--{what} ")) from None
        return text

    check.__name__ = what
    return check


def cmd_accuracy(args: argparse.Namespace) -> int:
    from pathlib import Path

    from bikeid.experiments.cli.args import atomic_write_text, parse_range
    from bikeid.experiments.testbed import accuracy as acc

    controllers = _names(args.controllers, acc.CONTROLLERS, "controllers")
    methods = _names(args.methods or ",".join(acc.METHODS), acc.METHODS, "methods")
    if args.quick and args.speeds:
        raise ValueError("--quick fixes the speeds; drop --speeds or --quick")
    if args.speeds:
        speeds = tuple(float(v) for v in parse_range(args.speeds, "--speeds", minimum=0.1))
    else:
        speeds = acc.QUICK_SPEEDS if args.quick else acc.FULL_SPEEDS
    out = Path(args.out)
    import sys

    from bikeid.dataset.files import check_owned_folder, owned_folder

    # an owned folder: its accuracy.json/.md are never another's files, two runs cannot mix
    owned = ("accuracy.json", "accuracy.md")
    check_owned_folder(out, "bikeid accuracy", names=owned)
    print(f"bikeid accuracy: writing into {out}/ (data cache, accuracy.json, accuracy.md)",
          file=sys.stderr)  # a default location: say where  # fmt: skip
    bar = terminal_progress("accuracy", json_output=args.json, unit="stage")
    with owned_folder(out, "bikeid accuracy", names=owned):
        result = acc.run_accuracy(
            out, controllers, methods, speeds, workers=args.workers, dask=args.dask,
            log=bar.write if bar else quiet, progress=bar, seeds=tuple(range(args.seeds)),
        )  # fmt: skip
        atomic_write_text(out / "accuracy.json", dump_json(result))
        atomic_write_text(out / "accuracy.md", acc.markdown(result))
    if args.json:
        print(dump_json(result))
    else:
        print(acc.table_text(result), end="")
        print(f"wrote {out / 'accuracy.json'} and {out / 'accuracy.md'}")
    return 0
