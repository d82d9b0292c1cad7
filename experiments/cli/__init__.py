"""The ``bikeid`` command line.

Each group of subcommands lives in a module of this package with a
``register(subparsers)`` function: :mod:`.plant` (``eig``, ``linearize``,
``critical-speeds``), :mod:`.simulate`, :mod:`.data` (``sweep``, ``stabilization``),
:mod:`.identify` (``identify``, ``export``, ``accuracy``), :mod:`.validate`,
:mod:`.reproduce`, :mod:`.measured` (``measured ...``, ``data fetch``), :mod:`.discover`
(``measured discover``), :mod:`.coverage`, :mod:`.consistency`;
:mod:`.args` holds the argument types and helpers they share, :mod:`.log_options` the
data options that parse into the one loader's :class:`~bikeid.dataset.logs.LogOptions`.
Handlers import the study modules lazily so that ``bikeid --help`` stays fast (start-up
time).  Any failure ends in one line on stderr, never a traceback (unless ``--debug``),
and a documented exit status (:data:`EXIT_CODES`, :mod:`bikeid.sim.errors`); a Python
warning becomes one ``note:`` line saying its consequence.
"""

from __future__ import annotations

import argparse
import importlib
import re
import signal
import sys
import traceback
import warnings

from bikeid.sim.blas import one_blas_thread
from bikeid.sim.errors import (
    EXIT_INPUT,
    EXIT_INTERNAL,
    EXIT_UNTRUSTWORTHY,
    EXIT_USAGE,
    UntrustworthyResult,
)

COMMAND_MODULES = (
    "bikeid.experiments.cli.plant",  # eig, linearize, critical-speeds
    "bikeid.experiments.cli.simulate",  # simulate
    "bikeid.experiments.cli.data",  # sweep, stabilization
    "bikeid.experiments.cli.identify",  # identify
    "bikeid.experiments.cli.validate",  # validate
    "bikeid.experiments.cli.reproduce",  # reproduce
    "bikeid.experiments.cli.measured",  # measured fit/evaluate, data fetch
    "bikeid.experiments.cli.discover",  # measured discover (after measured)
    "bikeid.experiments.cli.coverage",  # coverage
    "bikeid.experiments.cli.consistency",  # consistency
)

#: The exit statuses of ``bikeid`` (also in ``bikeid --help``).
EXIT_CODES = """\
exit status:
  0  success
  1  internal failure (a bug): rerun with --debug and report the traceback
  2  usage error: unknown option, missing or bad option value
  3  invalid input data or parameters (a file, a field, a value out of range)
  4  no trustworthy answer: unidentifiable or ill-conditioned fit, unstable model,
     diverged simulation, or the run fell where that is an error
  130 interrupted (Ctrl-C)
Errors are one line on stderr, "bikeid COMMAND: error: MESSAGE"; --debug (anywhere on
the command line) prints the traceback as well."""


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line usage error: ``bikeid sweep: error: ... (see --help)``."""

    def error(self, message: str):  # noqa: D102 - argparse's hook
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="bikeid",
        description="Whipple bicycle dynamics and closed-loop identification testbed.",
        epilog=EXIT_CODES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action=_Version, nargs=0, help="print the version and exit")
    parser.add_argument(
        "--debug", action="store_true", help="print the traceback of an error (anywhere)"
    )
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


class _Version(argparse.Action):
    """``--version``: the installed version, read only when asked (start-up time)."""

    def __call__(self, parser, namespace, values, option_string=None):  # noqa: D102
        parser.exit(0, _version() + "\n")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"bikeid {version('bikeid')}"
    except PackageNotFoundError:  # running from a source tree
        return "bikeid (not installed)"


def _chosen(parser: argparse.ArgumentParser, args: argparse.Namespace):
    """The innermost subparser the arguments selected, and its prog ("bikeid sweep")."""
    while True:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        name = getattr(args, subs[0].dest, None) if subs else None
        if not name or name not in subs[0].choices:
            return parser
        parser = subs[0].choices[name]


def _check_empty_values(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--opt=--`` hands a single-valued option an empty list, bypassing ``type=``; and
    ``--opt=`` an empty string (a file or folder named "" would mean the current folder)."""
    for action in parser._actions:
        if action.nargs is None and action.option_strings:
            value = getattr(args, action.dest, None)
            if value == []:
                parser.error(
                    f"argument {'/'.join(action.option_strings)}: expected one value, got "
                    f"'--' (write {action.option_strings[-1]} VALUE)"
                )
            if value == "" and action.default != "":
                parser.error(
                    f"argument {'/'.join(action.option_strings)}: expected a value, got an "
                    f"empty string (write {action.option_strings[-1]} VALUE)"
                )


#: Library messages name keyword arguments; on the command line the fix is an option or a
#: change of the data.  (pattern, replacement) applied to every error line.
_CLI_FIXES = (
    (r"pass delimiter=('[^']*') \(or the separator it uses\)",
     r"save it with commas as separators (bikeid reads comma-separated files; it looks "
     r"separated by \1)"),
    (r"; pass theta0=(?: \([^)]*\))?", "; give more informative data (longer runs, more "
     "excitation) or fit this speed with its neighbours (--speed-parameterized)"),
    (r"Fix one of them \(free=\.\.\.\)", "Fix one of them (leave it out of --free)"),
    (r"\(noise_model='kalman', a predictor", "(--noise-model kalman, a predictor"),
    (r"pass drop_unidentifiable=True \(CLI: --drop-unidentifiable\)",
     "give --drop-unidentifiable"),
)


def _message(exc: BaseException) -> str:
    text = str(exc).strip()
    if isinstance(exc, OSError) and exc.filename and exc.errno is not None:
        from bikeid.dataset.files import storage_error

        err = storage_error(exc, exc.filename)  # a full or read-only disk: the fix too
        if err is not exc:
            return str(err)
    if isinstance(exc, OSError) and exc.strerror:  # "[Errno 2] No such file ...: 'x'"
        text = f"{exc.strerror}: {exc.filename!r}" if exc.filename else exc.strerror
    elif isinstance(exc, MemoryError):
        text = f"out of memory ({text or 'MemoryError'}); use a smaller problem"
    elif "set_int_max_str_digits" in text:  # Python's own advice: no use to a bikeid user
        text = ("a number with more than 4300 digits in the input; write numbers of a physical "
                "size (at most 17 significant digits)")  # fmt: skip
    for pattern, cli_fix in _CLI_FIXES:  # the library's keyword advice, as this CLI's options
        text = re.sub(pattern, cli_fix, text)
    if "np." in text:  # numpy's repr leaks into f-strings ({x!r}): np.float64(9.98) -> 9.98
        text = re.sub(r"np\.(?:float|int|uint|complex)\d*\(([^()]*)\)", r"\1", text)
    elif isinstance(exc, OverflowError):
        text = f"a value is too large ({text}); use values of a physical size"
    lines = text.splitlines()
    return lines[0] if lines else type(exc).__name__


def main(argv: list[str] | None = None) -> int:
    """Run ``bikeid`` and return its exit status; never raises, never prints a traceback
    unless ``--debug`` is given.

    Parameters
    ----------
    argv : list of str, optional
        The arguments (default ``sys.argv[1:]``); ``--debug`` anywhere before ``--``.

    Returns
    -------
    int
        0 success, 1 internal failure, 2 usage error, 3 invalid input data or parameters,
        4 no trustworthy answer, 130 interrupted (:data:`EXIT_CODES`).
    """
    handler = signal.getsignal(signal.SIGINT)
    if getattr(handler, "__name__", "") == "_interrupted_while_starting":  # ours or __main__'s
        signal.signal(signal.SIGINT, signal.default_int_handler)  # KeyboardInterrupt again
    try:
        return _main(argv)
    except KeyboardInterrupt:  # while the parser was built (command modules imported)
        print("bikeid: interrupted", file=sys.stderr)
        return 130


def _main(argv: list[str] | None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv[: argv.index("--")] if "--" in argv else "--debug" in argv
    if debug:
        argv.remove("--debug")
    try:
        parser = build_parser()
    except Exception as exc:  # noqa: BLE001 - a broken installation: one line, not a traceback
        if debug:
            traceback.print_exc()
        print(f"bikeid: internal error ({type(exc).__name__}): {_message(exc)}; rerun with "
              "--debug and report it", file=sys.stderr)  # fmt: skip
        return EXIT_INTERNAL
    try:
        args = parser.parse_args(argv)
        chosen = _chosen(parser, args)
        _check_empty_values(chosen, args)
    except SystemExit as exc:  # argparse: --help/--version (0) or a usage error (2)
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    prog = chosen.prog
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    try:
        try:
            with warnings.catch_warnings(), one_blas_thread():  # small matrices: threads spin
                if not debug:  # no raw warning reaches a user: each becomes one note
                    warnings.showwarning = _warning_note  # (the caller's filters stand)
                    _seen_warnings.clear()
                return int(args.func(args) or 0)
        finally:  # progress bars end before any error line (experiments.progress)
            if "bikeid.experiments.progress" in sys.modules:
                sys.modules["bikeid.experiments.progress"].close_all()
    except BrokenPipeError:  # output piped into head & co.: stop quietly
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except UntrustworthyResult as exc:
        return _report(prog, exc, EXIT_UNTRUSTWORTHY, debug)
    except (ValueError, OSError, MemoryError, OverflowError) as exc:
        return _report(prog, exc, EXIT_INPUT, debug)
    except RecursionError as exc:  # a reader recursed: the input is nested too deeply
        return _report(prog, exc, EXIT_INPUT, debug, "input nested too deeply; flatten it")
    except Exception as exc:  # noqa: BLE001 - the last resort: no traceback by default
        if debug:
            traceback.print_exc()
        print(
            f"{prog}: internal error ({type(exc).__name__}): {_message(exc)}; rerun with "
            "--debug and report it",
            file=sys.stderr,
        )
        return EXIT_INTERNAL


#: What a warning of each category means for the result (the note printed with it).
WARNING_CONSEQUENCES = (
    (RuntimeWarning, "a numerical step met an overflow, a division by zero or an invalid "
     "value; the checks after it decide whether the result stands (a failed check refuses "
     "it); --debug shows where"),
    (DeprecationWarning, "a library bikeid uses will change; this result is not affected"),
    (FutureWarning, "a library bikeid uses will change; this result is not affected"),
    (Warning, "a library's caution about its own input; check the result that depends on "
     "it, or rerun with --debug to see where"),
)  # fmt: skip
_seen_warnings: set[tuple[type, str]] = set()


def _short_path(filename: str) -> str:
    """A warning's source file without the installation's folders (``numpy/linalg/...``)."""
    for marker in ("site-packages/", "dist-packages/"):
        if marker in filename:
            return filename.split(marker, 1)[1]
    parts = filename.replace("\\", "/").split("/")
    return "/".join(parts[-2:])


def _warning_note(message, category, filename, lineno, file=None, line=None) -> None:
    """``warnings.showwarning`` of the command line: one ``note:`` line per distinct warning,
    saying what it means for the result (:data:`WARNING_CONSEQUENCES`), no source line."""
    text = str(message).strip().splitlines()[0] if str(message).strip() else category.__name__
    if (category, text) in _seen_warnings:
        return
    _seen_warnings.add((category, text))
    consequence = next(c for k, c in WARNING_CONSEQUENCES if issubclass(category, k))
    print(f"note: {text} ({_short_path(str(filename))}): {consequence}", file=sys.stderr,
          flush=True)  # fmt: skip


def _report(prog: str, exc: BaseException, code: int, debug: bool, text: str = "") -> int:
    if debug:
        traceback.print_exc()
    print(f"{prog}: error: {text or _message(exc)}", file=sys.stderr)
    return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
