"""``bikeid validate``: a saved model against data (compare, k-step, resid, Bode vs data).

Loads the model with :func:`bikeid.ident.model_file.load_model`, reads the runs as
``bikeid identify`` does (same ``--format`` options), computes
:func:`bikeid.ident.validation_report.validate_model` one speed at a time, and prints one
screen: one row per speed (fit [%] per output, the whiteness verdict of
:mod:`bikeid.ident.structure`'s residual test, the Bode points inside the model's band),
then each note once.  With ``--out DIR`` it writes ``validation.json`` (every number) and
the figures of :mod:`bikeid.experiments.validation_plots` (one Bode figure per speed)
there; ``--json`` prints the JSON instead of the table.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from bikeid.experiments.cli.args import dump_json, integer, number
from bikeid.experiments.cli.log_options import FORMATS, add_data_options, log_options

#: Marker of the folders ``bikeid validate --out`` writes (in validation.json).
MARKER = "bikeid validate"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "validate",
        help="validate a saved model on data: fit %%, residual tests, Bode vs data",
        description=(
            "Compare a model saved by 'bikeid identify --out' with runs: measured vs "
            "simulated and k-step-predicted outputs (MATLAB compare's NRMSE fit in %), "
            "one-step residual whiteness and independence from the past input (the residual "
            "test of bikeid identify, chi-squared at family level 1 % over the speeds), and a "
            "nonparametric frequency response from T_delta to each output "
            "where the coherence shows excitation, with the model's 95 % Bode band (models with "
            "a parameter covariance). Data are read as by 'bikeid identify' "
            "(--format bikeid|csv|hdf5|sbw and its options); the data options the model "
            "file stores (format, columns, units, time, speed, flip, input, window) are "
            "reused unless given again."
        ),
    )
    p.add_argument("--model", required=True, metavar="MODEL.json", help="model file to validate")
    add_data_options(
        p,
        {k: FORMATS[k] for k in ("bikeid", "csv", "hdf5", "sbw")},
        input_help="the runs' torque signal [N m] used as the model's input T_delta (default "
        "T_delta)",
    )
    for action in p._actions:  # unset: taken from the model file (reuse_settings)
        if action.dest in REUSED:
            action.default = None
            action.help = (action.help or "").split(" (default")[0].split("; default")[0] + (
                f" (default: the model file's setting, else "
                f"{'none' if REUSED[action.dest] is None else repr(REUSED[action.dest])})")
    p.add_argument(
        "--k-step", type=integer(1, 1_000_000), default=10, metavar="K",
        help="horizon of the k-step-ahead prediction [samples] (default 10)",
    )  # fmt: skip
    p.add_argument(
        "--coherence", type=number(0.0, 0.99, lo_open=True), default=0.5,
        help="coherence below which a frequency counts as not excited (default 0.5)",
    )  # fmt: skip
    p.add_argument(
        "--out", default=None, metavar="DIR",
        help="write validation.json, compare_*.png, resid.png and the Bode figures (bode.png, "
        "or bode_v<speed>.png per speed) into DIR (a new or empty folder, or one written by "
        "bikeid validate)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the JSON instead of the table")
    p.set_defaults(func=cmd_validate)


#: Data options ``validate`` takes from the model file when not given, with the fallback
#: when the file stores none (models saved before the settings were stored, Python API).
REUSED = {"format": "bikeid", "columns": None, "units": None, "time": "t", "speed": None,
          "flip": "", "input": "T_delta", "start": None, "stop": None}  # fmt: skip


def reuse_settings(args: argparse.Namespace, settings: dict) -> list[str]:
    """Fill the data options not given on the command line from the model file's settings.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed options (unset data options are None).
    settings : dict
        The model file's ``settings`` (``bikeid identify``'s data options among them).

    Returns
    -------
    list of str
        ``--option value`` of each option taken from the model file.
    """
    taken = []
    for key, fallback in REUSED.items():
        if getattr(args, key, None) is not None:
            continue
        stored = settings.get(key)
        if key == "format" and stored not in (None, "bikeid", "csv", "hdf5", "sbw"):
            stored = None
        if key == "flip" and isinstance(stored, list):
            stored = ",".join(stored)
        if stored in (None, "", [], {}):
            setattr(args, key, fallback)
            continue
        setattr(args, key, stored)
        if stored != fallback:
            text = (",".join(f"{k}={v}" for k, v in stored.items())
                    if isinstance(stored, dict) else stored)  # fmt: skip
            taken.append(f"--{key.replace('_', '-')} {text}")
    return taken


def check_out_dir(out: str | Path) -> Path:
    """Refuse an output folder bikeid did not make for a validation (before any work).

    Parameters
    ----------
    out : str or Path
        The ``--out`` folder.

    Returns
    -------
    Path
        The folder (not created yet).

    Raises
    ------
    ValueError
        If ``out`` is a file or a link, or holds files not written by ``bikeid validate``
        (:func:`bikeid.dataset.files.owned_folder` makes the same check under its lock).
    """
    from bikeid.dataset.files import check_owned_folder

    out = Path(out)
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise ValueError(f"--out {out} is not a folder; give a new or empty folder")
    return check_owned_folder(out, MARKER, adopt=("validation.json",))


def _owned(out: Path | None):
    import contextlib

    from bikeid.dataset.files import owned_folder

    if out is None:
        return contextlib.nullcontext()
    return owned_folder(out, MARKER, adopt=("validation.json",))


def _model(path: str):
    from bikeid.ident.effects.experiment_model import ExperimentModel
    from bikeid.ident.model_file import load_model

    model = load_model(path)
    if isinstance(model, ExperimentModel):
        raise ValueError(
            f"{path} holds an experiment model (bikeid measured fit): validate it on the "
            "measured decays with 'bikeid measured evaluate --model'"
        )
    return model


def _speed_note(path: str, data_speeds) -> str | None:
    """A note when the data are at speeds the model was not identified at (None if not).

    A model of one speed (or per-speed fits) applies at those speeds; a model over speed
    at speeds within the identified range.  Tolerance: 2 % of the speed or 0.05 m/s.
    """
    from bikeid.ident.model_file import read_model_file

    ident = read_model_file(path).speeds
    if not ident:
        return None
    over_speed = read_model_file(path).kind in ("speed-canonical-pem", "greybox", "direct")
    outside = []
    for v in sorted({round(float(x), 3) for x in data_speeds}):
        tol = max(0.05, 0.02 * v)
        if over_speed:
            off = v < min(ident) - tol or v > max(ident) + tol
        else:
            off = all(abs(v - w) > tol for w in ident)
        if off:
            outside.append(v)
    if not outside:
        return None
    span = (f"{min(ident):g}-{max(ident):g} m/s (a model over speed, extrapolated outside)"
            if over_speed and len(ident) > 1 else f"{', '.join(f'{w:g}' for w in ident)} m/s")
    return (f"the model was identified at {span} but the data include "
            f"{', '.join(f'{v:g}' for v in outside)} m/s: its fit there tests an "
            "extrapolation, not the identified model; validate on data at the identified speeds")


def _num(x) -> str:
    import math

    return "n/a" if x is None or not math.isfinite(x) else f"{x:.1f}"


def _whiteness_text(row) -> str:
    """``white``, ``NOT: phi,delta`` or ``not tested (K = 0)`` of one speed's row."""
    if row.whiteness is None:
        return "not tested (K = 0)"
    bad = [o for o, t in row.whiteness.items() if not t["white"]]
    return f"NOT: {','.join(bad)}" if bad else "white"


def _independence_text(row) -> str:
    """``yes`` or ``NOT: phi,delta``: the residual independent of the past input."""
    bad = [o for o, t in row.independence.items() if not t["independent"]]
    return f"NOT: {','.join(bad)}" if bad else "yes"


def _band_text(frf: dict) -> str:
    if not frf["n_points"]:
        return "no excited points"
    if frf["n_inside"] is None:
        return f"{frf['n_points']} points, no band"
    return f"{frf['n_inside']}/{frf['n_points']} ({frf['n_consistent']} with own error)"


def table(report, model_path: str) -> str:
    """The printed summary: one line per speed (fit, whiteness, Bode band), then notes.

    Parameters
    ----------
    report : ValidationReport
        The validation.
    model_path : str
        The model file (for the heading).

    Returns
    -------
    str
        Lines ending in a newline: a heading of five lines, one line per speed and one for
        all runs, the residual tests' verdict, the Bode band's calibration and the notes
        (each said once); the details are in the JSON (``--json``, ``validation.json``).
    """
    from bikeid.ident.validation_report import _speed_list

    st = report.structure
    m = int(report.correlations[0].lags[-1]) if report.correlations else 0
    sim = report.headline == "simulation"
    what = "simulation" if sim else f"{report.k_step}-step prediction"
    lines = [
        f"{model_path} on {len(report.runs)} run(s) at {_speed_list(set(report.speeds))}",
        f"fit %: the {what}'s, 100 (1 - ||y - yhat|| / ||y - mean y||) (MATLAB compare)",
    ]
    if report.simulation_note:
        lines.append(report.simulation_note)
    lines += [
        f"whiteness: ident.structure's residual test, as bikeid identify's (one-step "
        f"residuals, lags 1..{m}, family level {st.level:g}: each test at p < "
        f"{st.per_test_level:.2g})",
        "independent: of the past T_delta (same test family); in band: Bode points of the "
        "data inside the model's 95 % band (of those excited)",
    ]
    white = [_whiteness_text(row) for row in report.per_speed]
    indep = [_independence_text(row) for row in report.per_speed]
    w1, w2 = max(len("whiteness"), *map(len, white)), max(len("independent"), *map(len, indep))
    head = f"{'v [m/s]':>7s} {'runs':>4s} " + "".join(f"{o:>9s}" for o in report.outputs)
    lines.append(f"{head}  {'whiteness':{w1}s}  {'independent':{w2}s}  in band")
    for row, wt, it in zip(report.per_speed, white, indep, strict=True):
        fits = row.fit_simulation if sim else row.fit_k_step
        lines.append(
            f"{row.speed:7g} {row.runs:4d} " + "".join(f"{_num(fits[o]):>9s}" for o in
                                                       report.outputs)
            + f"  {wt:{w1}s}  {it:{w2}s}  {_band_text(row.frf)}"
        )  # fmt: skip
    if len(report.per_speed) > 1:
        fits = report.fit if sim else report.fit_k_step
        all_band = report.band_summary()
        band = "" if all_band is None else _band_text(all_band)
        lines.append(f"{'all':>7s} {len(report.runs):4d} "
                     + "".join(f"{_num(fits[o]):>9s}" for o in report.outputs)
                     + f"  {'':{w1}s}  {'':{w2}s}  {band}")  # fmt: skip
    causes = st.causes()
    lines.append(f"residual tests reject: {causes}" if causes else
                 "residual tests: no test rejects")  # fmt: skip
    if report.band_summary() is not None:
        lines.append("Bode band: first-order, calibrated on the linear plant only "
                     "(docs/uncertainty.md); on the nonlinear plant or measured data it can be "
                     "too narrow")  # fmt: skip
    lines += [f"note: {n}" for n in report.notes]
    return "\n".join(lines) + "\n"


def _files_text(paths: list[Path]) -> str:
    """``val/validation.json, val/compare_1.png, ... (12 files in val)``: the first five."""
    names = [str(p) for p in paths]
    if len(names) <= 5:
        return ", ".join(names)
    return f"{', '.join(names[:5])}, ... ({len(names)} files in {paths[0].parent})"


def cmd_validate(args: argparse.Namespace) -> int:
    from bikeid.dataset.files import check_distinct_inputs, check_input_file, check_outputs
    from bikeid.dataset.logs import data_files as files_of
    from bikeid.dataset.logs import load_runs
    from bikeid.experiments.cli.args import atomic_write_text
    from bikeid.ident.model_file import read_model_file
    from bikeid.ident.validation_report import validate_model

    out = check_out_dir(args.out) if args.out else None
    check_input_file(args.model, "--model")
    saved = dict(read_model_file(args.model).settings or {})
    taken = reuse_settings(args, saved)
    # a grey-box/direct model's bicycle; without the simulated runs' noise-free signals,
    # which validation never reads (over half of a sweep's memory)
    options = replace(log_options(args, bicycle=saved.get("bicycle")), truth=False)
    data_files = files_of(args.file, options)
    check_outputs([out], [args.model, *data_files])
    check_distinct_inputs(data_files)
    with _owned(out):
        model = _model(args.model)
        runs = load_runs(args.file, options)
        if not runs:
            raise ValueError(f"{', '.join(args.file)} hold no runs")
        report = validate_model(model, runs, k_step=args.k_step, coherence_min=args.coherence)
        from bikeid.experiments.plots import angle_unit

        # angles in the user's unit: degrees unless their logs were in radians; then the runs
        # go (the report holds what the figures need), so the figures reuse their memory
        angle = angle_unit(runs)
        del runs
        doc = {"command": MARKER, "model": str(args.model), "data": list(map(str, args.file)),
               "settings_from_model": taken, **report.to_json()}  # fmt: skip
        note = _speed_note(args.model, report.speeds)
        if note:
            report = replace(report, notes=(*report.notes, note))
            doc["notes"] = [*doc.get("notes", []), note]
        written = []
        if out is not None:
            from bikeid.experiments.validation_plots import write_figures

            atomic_write_text(out / "validation.json", dump_json(doc) + "\n")
            written = [out / "validation.json"]
            written += write_figures(report, out, angle=angle)
    if args.json:
        print(dump_json(doc))
    else:
        if taken:
            print(f"data read with the model file's settings: {' '.join(taken)}")
        print(table(report, args.model), end="")
        if written:
            print(f"wrote {_files_text(written)}")
    return 0
