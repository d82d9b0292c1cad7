"""``bikeid reproduce [--out DIR] [--quick] [--workers N]``: both papers redone with the truth."""

from __future__ import annotations

import argparse

from bikeid.experiments.cli.args import MAX_WORKERS, integer
from bikeid.experiments.parallel import DASK_HELP


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "reproduce",
        help="redo every figure and table of Chen & Dao (2010) and Moore & Hubbard",
        description=(
            "Redo the figures and tables of Chen & Dao (2010) and Moore & Hubbard on the "
            "testbed: paper | bikeid identified | ground truth side by side in DIR/report.md, "
            "DIR/summary.json and PNG figures. Progress goes to stderr when it is a terminal."
        ),
    )
    p.add_argument(
        "--out",
        default="reproduce",
        metavar="DIR",
        help="output folder (created; default ./reproduce)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="fewer speeds, shorter runs (< 2 min); the report lists the settings",
    )
    p.add_argument(
        "--workers",
        type=integer(1, MAX_WORKERS),
        default=None,
        metavar="N",
        help="worker processes for the identification runs (default min(2, cores))",
    )
    p.add_argument("--dask", metavar="ADDRESS", help=DASK_HELP)
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.add_argument(
        "--bicycle",
        default="benchmark",
        help="parameter set for the Chen & Dao part (default benchmark)",
    )
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    import sys

    from bikeid.dataset.files import check_outputs, check_owned_folder, owned_folder
    from bikeid.experiments.papers.reproduce import reproduce
    from bikeid.experiments.progress import quiet, terminal_progress

    check_owned_folder(args.out, "bikeid reproduce")  # another's report.md is never replaced
    check_outputs([args.out], [args.bicycle])
    if not args.quiet:
        print(f"bikeid reproduce: writing into {args.out}/", file=sys.stderr)
    bar = terminal_progress("reproduce", unit="stage", quiet=args.quiet)
    before = user_files(args.out)  # files of an earlier run left unchanged are not counted
    with owned_folder(args.out, "bikeid reproduce"):
        reproduce(
            args.out, quick=args.quick, workers=args.workers, bicycle=args.bicycle,
            log=bar.write if bar else quiet, progress=bar, dask=args.dask,
        )  # fmt: skip
    if not args.quiet:  # the files written, also when stderr is not a terminal
        files = written_files(args.out, before)
        print(f"bikeid reproduce: wrote {len(files)} file{'s' if len(files) != 1 else ''}: "
              f"{', '.join(map(str, files))}",
              file=sys.stderr)  # fmt: skip
    return 0


def user_files(folder) -> dict:
    """The files of ``folder`` meant for the user, each with its identity (inode, mtime).

    Parameters
    ----------
    folder : str or path-like
        The output folder (missing: no files).

    Returns
    -------
    dict of pathlib.Path to tuple
        Path -> ``(st_ino, st_mtime_ns, st_size)``; hidden files (the folder's marker and
        lock, any name starting with ``.``) left out.
    """
    from pathlib import Path

    root = Path(folder)
    if not root.is_dir():
        return {}
    out = {}
    for p in root.rglob("*"):
        if p.is_file() and not any(part.startswith(".") for part in p.relative_to(root).parts):
            st = p.stat()
            out[p] = (st.st_ino, st.st_mtime_ns, st.st_size)
    return out


def written_files(folder, before: dict) -> list:
    """The files written for the user since ``before`` (:func:`user_files` then).

    Parameters
    ----------
    folder : str or path-like
        The output folder.
    before : dict
        :func:`user_files` of the folder before the run: a file left unchanged by this
        run (same inode, time and size) is not counted.

    Returns
    -------
    list of pathlib.Path
        Sorted.
    """
    return sorted(p for p, key in user_files(folder).items() if before.get(p) != key)
