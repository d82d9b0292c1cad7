"""The ``bikeid`` command line.

Each group of subcommands lives in its own ``experiments.cmd_*`` module with a
``register(subparsers)`` function; handlers import heavy modules lazily so that
``bikeid --help`` stays fast.  Bad input ends in a one-line ``bikeid: error: ...``
(exit status 2), never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

COMMAND_MODULES = (
    "bikeid.experiments.cmd_plant",  # eig, linearize, critical-speeds
    "bikeid.experiments.cmd_simulate",  # simulate
    "bikeid.experiments.cmd_data",  # sweep, stabilization
    "bikeid.experiments.cmd_ident",  # identify
    "bikeid.experiments.cmd_reproduce",  # reproduce
    "bikeid.experiments.cmd_measured",  # measured fit/evaluate, data fetch
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bikeid",
        description="Whipple bicycle dynamics and closed-loop identification testbed.",
    )
    parser.add_argument("--version", action="version", version=_version())
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:  # a command group not built yet
            if exc.name != name:
                raise
            continue
        module.register(sub)
    return parser


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"bikeid {version('bikeid')}"
    except PackageNotFoundError:  # running from a source tree
        return "bikeid (not installed)"


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:  # output piped into head & co.: stop quietly
        sys.stderr.close()
        return 0
    except (ValueError, OSError) as exc:
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"bikeid: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("bikeid: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
