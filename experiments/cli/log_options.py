"""The data options of ``identify``, ``validate`` and ``measured``, parsed into a LogOptions.

The command line only parses: :func:`add_data_options` declares the options and
:func:`log_options` turns them into a :class:`bikeid.dataset.logs.LogOptions`, the value the
one loader (:func:`bikeid.dataset.logs.load_runs`) reads with every check.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from typing import Any

from bikeid.dataset.logs import FORMATS, LogOptions
from bikeid.experiments.cli.args import mapping_arg, number, positive_speed, skipped_checks

__all__ = ["FORMATS", "add_data_options", "log_options", "speed_arg"]

#: ``--speed``: a speed with an optional unit of the one unit table (``5``, ``5m/s``,
#: ``14.4km/h``, ``9mph``, ``KM/H``) in m/s, in (0, MAX_SPEED] (``args.positive_speed``).
speed_arg = positive_speed


def add_data_options(
    p: argparse.ArgumentParser, formats: Mapping[str, str], input_help: str | None,
    files: str = "+",
) -> None:  # fmt: skip
    """The data arguments of ``identify`` and ``validate``, parsed by :func:`log_options`.

    Adds FILE..., ``--format``, the importer options ``--columns``, ``--units``, ``--time``,
    ``--speed``, ``--flip`` (csv/hdf5 logs) and ``--input`` (the torque signal used as
    T_delta, :func:`bikeid.dataset.logs.with_input`).

    Parameters
    ----------
    p : argparse.ArgumentParser
        The command's parser.
    formats : mapping of str to str
        The ``--format`` choices (a subset of :data:`FORMATS`) and their help; the first is
        the default.
    input_help : str or None
        Help text of ``--input``; None: no ``--input`` (a command with its own, e.g.
        ``measured evaluate``).
    files : str, optional
        ``nargs`` of FILE (default ``"+"``; ``"*"`` where the files may come from elsewhere,
        e.g. ``measured fit --data``).

    Returns
    -------
    None
    """
    p.add_argument("file", nargs=files, help="run files (bikeid HDF5) or logs (--format)")
    p.add_argument(
        "--format", choices=tuple(formats), default=next(iter(formats)),
        help="; ".join(f"{k}: {v}" for k, v in formats.items()),
    )  # fmt: skip
    p.add_argument(
        "--columns", type=mapping_arg("--columns"), default=None, metavar="NAME=COL,...",
        help="csv/hdf5: bikeid signal -> your column (CSV header) or dataset path (HDF5)",
    )  # fmt: skip
    p.add_argument(
        "--units", type=mapping_arg("--units"), default=None, metavar="NAME=UNIT,...",
        help="csv/hdf5: units of non-SI columns, e.g. phi=deg,v=km/h,t=ms",
    )  # fmt: skip
    p.add_argument("--time", default="t", help="csv/hdf5: the time column / dataset (default t)")
    p.add_argument(
        "--speed", type=speed_arg, default=None, metavar="SPEED",
        help="csv/hdf5: constant speed when the log has no speed column, with a unit: 5m/s, "
        "14.4km/h (a bare number is m/s)",
    )  # fmt: skip
    p.add_argument(
        "--start", type=number(-1e9, 1e9, unit="s"), default=None,
        help="keep the samples at t >= START [s, the run's own time base] (default: all)",
    )  # fmt: skip
    p.add_argument(
        "--stop", type=number(-1e9, 1e9, unit="s"), default=None,
        help="keep the samples at t < STOP [s] (default: all)",
    )  # fmt: skip
    p.add_argument(
        "--speed-tolerance", type=number(0.0, 10.0, unit="m/s"), default=0.25,
        help="runs whose mean speeds lie within this of each other pool into one model at "
        "their weighted mean speed; also the speed range of a constant-speed stretch when a "
        "log's speed varies [m/s] (default 0.25; 0 pools equal speeds only)",
    )  # fmt: skip
    p.add_argument(
        "--min-stretch", type=number(0.0, 1e6, unit="s"), default=10.0,
        help="shortest constant-speed stretch kept when a log's speed varies [s] (default 10)",
    )  # fmt: skip
    p.add_argument(
        "--min-speed", type=number(0.0, 100.0, unit="m/s"), default=0.5,
        help="stretches slower than this are dropped when a log's speed varies [m/s] "
        "(default 0.5)",
    )  # fmt: skip
    p.add_argument(
        "--skip-check", default="", metavar="NAME,...",
        help="checks not to run on a log you know is odd (a note says so): csv/hdf5: "
        "angle-bounds, rate-bounds, speed-bounds, torque-bounds, force-bounds (physical "
        "ranges); sample-period, rate-derivative, signs (against --bicycle), informativity "
        "(default: none)",
    )  # fmt: skip
    p.add_argument("--no-checks", action="store_true", help="skip every check of --skip-check")
    p.add_argument(
        "--flip", default="", metavar="NAME,...",
        help="csv/hdf5: signals logged with the opposite sign (Meijaard: positive right)",
    )  # fmt: skip
    if input_help is not None:
        p.add_argument("--input", default="T_delta", metavar="SIGNAL", help=input_help)


def log_options(
    args: argparse.Namespace, bicycle: Any = None, input: str | None = None
) -> LogOptions:
    """The :class:`~bikeid.dataset.logs.LogOptions` of parsed :func:`add_data_options`.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed options (absent ones take the loader's defaults).
    bicycle : str or BicycleParameters, optional
        The nominal bicycle whose equations check the signs (``--bicycle``); for the
        steer-by-wire logs their own bicycle when not given.
    input : str, optional
        The steer-torque signal (default ``args.input``, else ``"T_delta"``; ``measured``
        uses ``--input``'s name for its drive and passes ``"T_delta"``).

    Returns
    -------
    LogOptions
    """
    fmt = getattr(args, "format", "bikeid")
    if bicycle is None and fmt == "sbw":
        bicycle = "steer-by-wire"
    return LogOptions(
        format=fmt, columns=getattr(args, "columns", None), units=getattr(args, "units", None),
        time=getattr(args, "time", "t"), speed=getattr(args, "speed", None),
        flip=getattr(args, "flip", "") or (), skip=tuple(skipped_checks(args)),
        no_checks=bool(getattr(args, "no_checks", False)), start=getattr(args, "start", None),
        stop=getattr(args, "stop", None),
        speed_tolerance=getattr(args, "speed_tolerance", 0.25),
        min_stretch=getattr(args, "min_stretch", 10.0),
        min_speed=getattr(args, "min_speed", 0.5),
        input=input or getattr(args, "input", None) or "T_delta", bicycle=bicycle,
    )  # fmt: skip
