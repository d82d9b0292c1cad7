"""The error types every stage raises, and the ``bikeid`` exit status each maps to.

Both are :class:`ValueError` subclasses, so existing ``except ValueError`` code keeps
working.  The command line (:mod:`bikeid.experiments.cli`) maps them to exit codes:

======  ===================================================================
status  meaning
======  ===================================================================
0       success
1       internal failure (a bug: rerun with ``--debug`` and report it)
2       usage error (argparse: unknown option, bad option value)
3       invalid input data or parameters (:class:`InputError`, and a plain
        ``ValueError``/``OSError``/``MemoryError``/``OverflowError``)
4       a computation that cannot give a trustworthy answer
        (:class:`UntrustworthyResult`: unidentifiable regression, unstable
        predictor, diverged simulation, a run that fell)
======  ===================================================================
"""

from __future__ import annotations

import os

__all__ = ["EXIT_INPUT", "EXIT_INTERNAL", "EXIT_UNTRUSTWORTHY", "EXIT_USAGE", "InputError",
           "UntrustworthyResult", "check_memory", "memory_limit"]  # fmt: skip

#: Exit status of an internal failure (an unexpected exception).
EXIT_INTERNAL = 1
#: Exit status of a usage error (argparse).
EXIT_USAGE = 2
#: Exit status of invalid input data or parameters.
EXIT_INPUT = 3
#: Exit status of a computation whose answer cannot be trusted.
EXIT_UNTRUSTWORTHY = 4


class InputError(ValueError):
    """Invalid input data or parameters: a file, a field or a value the user can fix.

    Attributes
    ----------
    args : tuple
        The one-line message naming the problem and the fix.
    """


class UntrustworthyResult(ValueError):
    """A computation ran on valid input but cannot give a trustworthy answer.

    Raised for an unidentifiable (ill-conditioned) regression, an unstable predictor, a
    diverged simulation or a run that fell where that is an error.

    Attributes
    ----------
    args : tuple
        The one-line message naming the reason and what to try instead.
    """


def memory_limit() -> int:
    """Bytes one array may take: half the machine's physical memory (8 GiB if unknown).

    Returns
    -------
    int
        The limit [bytes].
    """
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not POSIX
        total = 16 * 2**30
    return int(total) // 2


def check_memory(samples: float, channels: int, what: str, fix: str) -> None:
    """Refuse, before allocating, an array of ``samples x channels`` float64 too large.

    Parameters
    ----------
    samples : float
        Number of rows (may be a float: ``duration / dt`` before rounding).
    channels : int
        Number of columns.
    what : str
        What would be allocated, named in the message (e.g. ``"the simulation"``).
    fix : str
        What to change (e.g. ``"shorten --duration or raise --dt"``).

    Raises
    ------
    InputError
        If ``samples * channels * 8`` bytes exceed :func:`memory_limit`, naming both sizes.
    """
    need = float(samples) * channels * 8.0
    limit = memory_limit()
    if not need <= limit:
        raise InputError(
            f"{what} needs {_size(need)} ({samples:.3g} samples x {channels} channels x 8 "
            f"bytes), more than the {_size(limit)} allowed (half the memory); {fix}"
        )


def _size(nbytes: float) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if nbytes < 1024 or unit == "PiB":
            return f"{nbytes:.3g} {unit}"
        nbytes /= 1024
    return f"{nbytes:.3g} PiB"  # pragma: no cover
