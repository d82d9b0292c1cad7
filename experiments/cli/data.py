"""Data commands: ``sweep`` (closed-loop runs to HDF5) and ``stabilization`` (which
controller keeps the bicycle upright at which speed)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from bikeid.controllers.registry import STUDY_CONTROLLERS
from bikeid.experiments.cli.args import (
    MAX_WORKERS,
    atomic_write_text,
    dump_json,
    duration_value,
    integer,
    number,
    parse_range,
    range_text,
)
from bikeid.experiments.parallel import DASK_HELP
from bikeid.experiments.progress import on_terminal

CONTROLLER_HELP = (  # "fuzzy, pid or pole (...)", from controllers.registry
    f"{', '.join(STUDY_CONTROLLERS[:-1])} or {STUDY_CONTROLLERS[-1]} "
    "(pole placement with integral action)"
)


SPEEDS = range_text("--speeds", 1e-6)
SPEEDS_HELP = "start:stop:step [m/s], stop included (speeds in (0, 100] m/s)"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sweep",
        help="closed-loop runs over speeds and seeds into one HDF5 file (resumable)",
        description="Simulate one controller at every speed and seed (chirp roll reference, "
        "uniform steer-torque dither, sensor noise) on the nonlinear Whipple model and store "
        "the runs in FILE.h5. Interrupted, the same command finishes only the missing runs. "
        "Results are bit-identical for any --workers.",
    )
    p.add_argument("--controller", type=_controller_arg, required=True, help=CONTROLLER_HELP)
    p.add_argument("--speeds", type=SPEEDS, default="1:15:0.5", help=SPEEDS_HELP)
    p.add_argument("--duration", type=duration_value, default=50.0, help="run length [s]")
    p.add_argument(
        "--seeds",
        type=_seeds_arg,
        default="0:4",
        help="seeds: a:b (b included), a:b:step or a list",
    )
    p.add_argument("--out", required=True, help="output HDF5 file (.h5)")
    _common(p)
    p.set_defaults(func=cmd_sweep)

    p = sub.add_parser(
        "stabilization",
        help="table: which controller stays upright at which speed",
        description="Run each controller at each speed with a chirp roll reference and "
        "dither on the nonlinear model; print a markdown table and write FILE.json and "
        "FILE.md (upright?, RMS roll tracking error, peak steer torque).",
    )
    p.add_argument("--speeds", type=SPEEDS, default="1:15:0.5", help=SPEEDS_HELP)
    p.add_argument("--duration", type=duration_value, default=50.0, help="run length [s]")
    p.add_argument(
        "--controllers",
        type=_controllers_arg,
        default=",".join(STUDY_CONTROLLERS),
        help=f"comma list of: {CONTROLLER_HELP}",
    )
    p.add_argument("--out", default="stabilization", help="writes OUT.json and OUT.md")
    _common(p)
    p.set_defaults(func=cmd_stabilization)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bicycle", default="benchmark", help="bicycle name (see `bikeid eig -h`)")
    p.add_argument(
        "--dither",
        type=number(0.0, 1e3, unit="N m"),
        default=1.0,
        help="uniform dither amplitude [N m] (0 = none)",
    )
    p.add_argument(
        "--chirp-deg",
        type=number(0.0, 45.0, unit="deg"),
        default=None,
        help="roll chirp amplitude [deg] (0.05-0.5 Hz), 0 = no reference; default: sweep "
        "0.5/1.5/3 deg below 3 / 3-6 / above 6 m/s (the identification design), "
        "stabilization 3 deg",
    )
    p.add_argument("--sensors", choices=("default", "ideal"), default="default")
    p.add_argument(
        "--rate", type=number(0.0, 1e4, lo_open=True, unit="Hz"), default=100.0,
        help="sensor sample rate [Hz]",
    )  # fmt: skip
    p.add_argument(
        "--workers", type=integer(1, MAX_WORKERS), default=1, help="local worker processes"
    )
    p.add_argument(
        "--dask", metavar="ADDRESS", help=DASK_HELP
    )
    p.add_argument(
        "--no-progress",
        action="store_true",
        help="no progress bar on stderr (there is one only when stderr is a terminal)",
    )


#: Most runs one sweep or stabilization table may hold (the product of its options).
MAX_RUNS = 100_000
#: Bytes a stored run takes per sample (about 27 float64 datasets: signals, truth, dither,
#: reference, time; measured: 215 bytes per sample), for the free-space check.
BYTES_PER_SAMPLE = 27 * 8


def _check_grid(n_a: int, n_b: int, what: str) -> int:
    """Refuse a grid whose options are each within their caps but whose product is not."""
    from bikeid.sim.errors import InputError

    runs = n_a * n_b
    if runs > MAX_RUNS:
        raise InputError(
            f"{what} make {n_a:,} x {n_b:,} = {runs:,} runs, more than {MAX_RUNS:,}; use a "
            "larger --speeds step or fewer values"
        )
    return runs


def _options(args: argparse.Namespace) -> dict:
    from bikeid.sim.errors import check_memory
    from bikeid.sim.parameters import by_name

    # before any file or folder is made: one run's records must fit in memory
    check_memory(args.duration * args.rate + 1, 45, f"a {args.duration:g} s run at "
                 f"{args.rate:g} Hz", "shorten --duration or lower --rate")  # fmt: skip

    by_name(args.bicycle)  # fail early on a bad name
    chirp = args.chirp_deg
    return {
        "bicycle": args.bicycle,
        "dither": args.dither,
        "chirp_amplitude": None if chirp is None else math.radians(chirp),
        "reference": "chirp" if chirp is None or chirp > 0 else "zero",
        "sensors": args.sensors,
        "sensor_rate": args.rate,
        "sample_time": 1.0 / args.rate,
    }


def _seeds(text: str) -> tuple[int, ...]:
    """``a:b`` (step 1, b included), ``a:b:step``, a comma list or one seed."""
    if text.count(":") == 1:
        text = text + ":1"
    values = parse_range(text, "--seeds", minimum=0, maximum=2**32 - 1)
    if any(v != int(v) for v in values):
        raise ValueError(f"--seeds {text!r}: seeds must be integers")
    return tuple(int(v) for v in values)


def _controller_arg(text: str) -> str:
    if text not in STUDY_CONTROLLERS:
        raise argparse.ArgumentTypeError(
            f"unknown controller {text!r}; choose one of {', '.join(STUDY_CONTROLLERS)}"
        )
    return text


def _controllers_arg(text: str) -> str:
    names = [c.strip() for c in text.split(",") if c.strip()]
    bad = [c for c in names if c not in STUDY_CONTROLLERS]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"unknown {bad}; give a comma list of {', '.join(STUDY_CONTROLLERS)}"
        )
    return text


def _seeds_arg(text: str) -> str:
    try:
        _seeds(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--seeds ")) from None
    return text


def cmd_sweep(args: argparse.Namespace) -> int:
    from bikeid.experiments.testbed.sweep import SweepSpec, run_sweep

    out = Path(args.out)
    if out.suffix not in (".h5", ".hdf5"):
        raise ValueError(f"--out {args.out!r}: a sweep's output must end in .h5 or .hdf5")
    if out.exists():  # checked before the sweep makes its OUT.parts folder
        import h5py

        if not out.is_file() or not h5py.is_hdf5(out):
            raise ValueError(
                f"--out {args.out!r} exists and is not an HDF5 file; a sweep resumes only its "
                "own output: give another name, or delete or rename the file"
            )
    from bikeid.dataset.files import check_free_space, check_output_path, check_outputs

    check_output_path(out)
    check_outputs([out, Path(f"{out}.parts")], [args.bicycle])
    speeds = parse_range(args.speeds, "--speeds", minimum=1e-6)
    seeds = _seeds(args.seeds)
    runs = _check_grid(len(speeds), len(seeds), "--speeds x --seeds")
    # the parts and the assembled file exist together for a moment: both must fit
    options = _options(args)  # one run must fit in memory (checked first)
    check_free_space(out, 2 * runs * (args.duration * args.rate + 1) * BYTES_PER_SAMPLE)
    spec = SweepSpec(args.controller, tuple(speeds), seeds, args.duration, **options)
    report = run_sweep(
        spec, args.out, workers=args.workers, dask=args.dask,
        progress=not args.no_progress and on_terminal(),
    )  # fmt: skip
    print(report.summary())
    return 0


def cmd_stabilization(args: argparse.Namespace) -> int:
    from bikeid.experiments.testbed.sweep import (
        CONTROLLERS,
        stabilization_counts,
        stabilization_markdown,
        stabilization_table,
    )

    speeds = parse_range(args.speeds, "--speeds", minimum=1e-6)
    controllers = [c.strip() for c in args.controllers.split(",") if c.strip()]
    bad = [c for c in controllers if c not in CONTROLLERS]
    if bad or not controllers:
        raise ValueError(f"--controllers: unknown {bad}; choose from {', '.join(CONTROLLERS)}")
    _check_grid(len(speeds), len(controllers), "--speeds x --controllers")
    targets = _stabilization_targets(args.out, args.bicycle)
    if args.chirp_deg is None:
        args.chirp_deg = 3.0  # a tracking test: the same 3 deg chirp at every speed
    options = _options(args)
    rows = stabilization_table(
        tuple(speeds),
        args.duration,
        controllers,
        workers=args.workers,
        dask=args.dask,
        progress=not args.no_progress and on_terminal(),
        **options,
    )
    c = stabilization_counts(rows)
    table = stabilization_markdown(rows) + (
        f"\n{c['upright']} upright, {c['fell']} fell, {c['failed']} failed numerically (not a "
        f"fall: no verdict on the controller), {c['error']} design failed\n"
    )
    print(table, end="")
    for r in rows:
        if r.get("stop") and not r["stop"]["physical"]:
            print(f"{r['controller']} at {r['speed']:g} m/s: {r['stop']['message']}",
                  file=sys.stderr)  # fmt: skip
    out = targets[0].with_suffix("")
    settings = {"speeds": list(speeds), "duration": args.duration, **options}
    atomic_write_text(
        out.with_name(out.name + ".json"), dump_json({"settings": settings, "rows": rows}) + "\n"
    )
    header = (
        f"# Stabilization on the nonlinear Whipple model ({args.bicycle})\n\n"
        f"Chirp roll reference {args.chirp_deg} deg, 0.05-0.5 Hz over {args.duration} s; "
        f"uniform dither +-{args.dither} N m; {args.sensors} sensors at {args.rate} Hz; "
        f"controller period {1 / args.rate} s. RMS error of the true roll against the "
        "reference over the whole run (until a fall); peak of the applied steer torque.\n\n"
    )
    atomic_write_text(out.with_name(out.name + ".md"), header + table)
    print(f"wrote {out}.json and {out}.md", file=sys.stderr)
    return 0


#: First line of the markdown ``bikeid stabilization`` writes (how it knows its own file).
STABILIZATION_HEAD = "# Stabilization on the nonlinear Whipple model"


def _stabilization_targets(text: str, bicycle: str) -> list[Path]:
    """OUT.json and OUT.md, said on stderr, refused if either is a file bikeid did not write."""
    from bikeid.dataset.files import check_output_path, check_outputs
    from bikeid.sim.errors import InputError

    out = Path(text)
    if out.suffix in (".json", ".md"):
        out = out.with_suffix("")
    targets = [out.with_name(out.name + ".json"), out.with_name(out.name + ".md")]
    for t in targets:
        check_output_path(t)
        if t.is_file():
            try:
                with open(t, encoding="utf-8") as fh:
                    head = fh.read(4096)
            except (OSError, UnicodeDecodeError):
                head = ""
            ours = head.startswith(STABILIZATION_HEAD) if t.suffix == ".md" else (
                head.startswith("{") and '"settings"' in head)  # fmt: skip
            if not ours:
                raise InputError(
                    f"{t} exists and was not written by bikeid stabilization; bikeid does not "
                    "overwrite it: give --out NAME (writes NAME.json and NAME.md)"
                )
    check_outputs(targets, [bicycle])
    print(f"bikeid stabilization: will write {targets[0]} and {targets[1]}", file=sys.stderr)
    return targets
