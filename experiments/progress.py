"""Progress of the long commands: a bar on a terminal, one line per stage elsewhere.

Library functions with long loops (effect selection, the accuracy table, the reproduction)
take a callback ``progress(done, total, label)`` instead of printing: ``done`` of ``total``
steps finished, ``label`` naming the current step (a speed, a candidate effect, a stage).  A
new ``total`` starts a new stage (the bar is reset).  They skip the call when the callback
is None, so a script or a test that passes nothing gets no output.  (The sweeps,
:func:`bikeid.experiments.testbed.sweep.run_sweep` and ``stabilization_table``, draw their own
``tqdm`` bar when called with ``progress=True``; their commands ask for it only where
:func:`on_terminal` is true.)

The command handlers make the callback with :func:`terminal_progress`: a ``tqdm`` bar on
stderr when stderr is a terminal, one line per stage (:class:`LineProgress`) when it is not
(a batch job or a notebook sees what ran), None with ``--json`` or ``--quiet`` (stdout is
the JSON and stderr stays empty unless there is an error).  :func:`stage_lines` prints a
command's own stage lines and the files it wrote the same way.  Log lines go through the
bar's :meth:`TerminalProgress.write` (or :func:`quiet` without one).  ``bikeid`` closes
open bars when a command ends
(:func:`close_all`).  ``tqdm`` is imported only when a bar is drawn, so start-up
is unchanged.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any, TextIO

__all__ = [
    "ProgressCallback",
    "TerminalProgress",
    "close_all",
    "on_terminal",
    "LineProgress",
    "quiet",
    "stage_lines",
    "terminal_progress",
]

#: Bars drawn and not yet closed (:func:`close_all`).
_OPEN: list[TerminalProgress] = []

#: ``progress(done, total, label)``: ``done`` of ``total`` steps finished [counts];
#: ``label`` names the current step.
ProgressCallback = Callable[[int, int, str], None]


def quiet(msg: str) -> None:
    """A ``log`` callback that drops its message (the non-terminal counterpart of
    :meth:`TerminalProgress.write`).

    Parameters
    ----------
    msg : str
        The message, ignored.
    """


_drop = quiet  # (the name ``quiet`` is an argument of the functions below)


class TerminalProgress:
    """A progress bar on a terminal stream, called as ``bar(done, total, label)``.

    Parameters
    ----------
    desc : str
        What the bar counts (shown before it, e.g. ``"identify"``).
    stream : text stream
        Where the bar is drawn (a terminal; :func:`terminal_progress` checks).
    unit : str, optional
        Name of one step (``"fit"``, ``"run"``, ``"stage"``).
    """

    def __init__(self, desc: str, stream: TextIO, unit: str = "step") -> None:
        # lazy: `bikeid --help` imports this module; tqdm loads only when a bar is drawn
        from tqdm import tqdm

        self._tqdm = tqdm
        self._stream = stream
        self._options = {"desc": desc, "unit": unit, "file": stream, "dynamic_ncols": True}
        self._bar: Any = None  # drawn at the first call, when the total is known
        _OPEN.append(self)

    def __call__(self, done: int, total: int, label: str = "") -> None:
        """Show ``done`` of ``total`` steps; a changed ``total`` starts a new stage.

        Parameters
        ----------
        done : int
            Steps finished, 0 <= done <= total.
        total : int
            Steps in this stage.
        label : str, optional
            The current step (shown after the bar).
        """
        if self._bar is None:
            self._bar = self._tqdm(total=total, **self._options)
        elif total != self._bar.total:
            self._bar.reset(total=total)
        self._bar.set_postfix_str(label, refresh=False)
        if done >= self._bar.n:
            self._bar.update(done - self._bar.n)
        else:
            self._bar.n = done
        self._bar.refresh()  # every call: the steps are slow (fits, runs, stages)

    def write(self, msg: str) -> None:
        """Print a line above the bar (a ``log`` callback that keeps the bar intact).

        Parameters
        ----------
        msg : str
            The line, without its newline.
        """
        if self._bar is None:
            print(msg, file=self._stream, flush=True)
        else:
            self._tqdm.write(msg, file=self._stream)

    def close(self) -> None:
        """Finish the bar (leaves its last state on the terminal); closing twice is harmless."""
        if self._bar is not None:
            self._bar.close()
        if self in _OPEN:
            _OPEN.remove(self)

    def __enter__(self) -> TerminalProgress:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class LineProgress:
    """Progress as plain lines (a batch job, a notebook): ``desc: [done/total] label``.

    A line is printed when the label or the stage (``total``) changes, so a step is
    reported once when it starts, not at every call; :meth:`write` prints a log line.

    Parameters
    ----------
    desc : str
        What is counted (e.g. ``"identify"``), the prefix of every line.
    stream : text stream
        Where the lines go (stderr).
    """

    def __init__(self, desc: str, stream: TextIO) -> None:
        self._desc, self._stream, self._last = desc, stream, None

    def __call__(self, done: int, total: int, label: str = "") -> None:
        """Print ``desc: [done/total] label`` when the label or the stage changed.

        Parameters
        ----------
        done : int
            Steps finished.
        total : int
            Steps in this stage.
        label : str, optional
            The current step.
        """
        key = (total, label)
        if key != self._last:
            self._last = key
            print(f"{self._desc}: [{done}/{total}] {label}".rstrip(), file=self._stream,
                  flush=True)  # fmt: skip

    def write(self, msg: str) -> None:
        """Print a log line.

        Parameters
        ----------
        msg : str
            The line, without its newline.
        """
        print(msg, file=self._stream, flush=True)

    def close(self) -> None:
        """Nothing to close (kept for the interface of :class:`TerminalProgress`)."""


def stage_lines(
    desc: str, *, json_output: bool = False, quiet: bool = False, stream: TextIO | None = None
) -> Callable[[str], None]:
    """A ``say(msg)`` callback for a command's stages: ``desc: msg`` on stderr.

    Lines are printed whether or not stderr is a terminal (a batch job sees what ran and
    the files written), except with ``--json`` or ``--quiet``.

    Parameters
    ----------
    desc : str
        The command (prefix of every line).
    json_output : bool, optional
        The command prints JSON: no lines.
    quiet : bool, optional
        ``--quiet``: no lines.
    stream : text stream, optional
        Where to print (default ``sys.stderr``, looked up at call time).

    Returns
    -------
    callable
        ``say(msg)``; :func:`quiet` when the lines are off.
    """
    if json_output or quiet:
        return _drop

    def say(msg: str) -> None:
        print(f"{desc}: {msg}", file=sys.stderr if stream is None else stream, flush=True)

    return say


def terminal_progress(
    desc: str,
    *,
    json_output: bool = False,
    unit: str = "step",
    stream: TextIO | None = None,
    quiet: bool = False,
    lines: bool = True,
) -> TerminalProgress | LineProgress | None:
    """A progress bar for a command, or None where a bar would get in the way.

    Parameters
    ----------
    desc : str
        What the bar counts (e.g. ``"identify"``).
    json_output : bool, optional
        The command prints JSON (``--json``): no bar, so stderr stays empty.
    unit : str, optional
        Name of one step.
    stream : text stream, optional
        Where to draw (default ``sys.stderr``, looked up at call time).
    quiet : bool, optional
        ``--quiet``: no progress at all.
    lines : bool, optional
        Off a terminal, report each stage as a line (:class:`LineProgress`); False keeps
        stderr empty there.

    Returns
    -------
    TerminalProgress or LineProgress or None
        A bar when ``stream`` is a terminal (``isatty()``); stage lines when it is not and
        ``lines`` is true; None with ``json_output`` or ``quiet`` (pass it on: the library
        functions then report nothing).
    """
    stream = sys.stderr if stream is None else stream
    if json_output or quiet:
        return None
    if not on_terminal(json_output=json_output, stream=stream):
        return LineProgress(desc, stream) if lines else None
    return TerminalProgress(desc, stream, unit)


def on_terminal(*, json_output: bool = False, stream: TextIO | None = None) -> bool:
    """Whether a command should show progress: ``stream`` is a terminal and no JSON is printed.

    Parameters
    ----------
    json_output : bool, optional
        The command prints JSON (``--json``).
    stream : text stream, optional
        The stream (default ``sys.stderr``, looked up at call time).

    Returns
    -------
    bool
        True when ``stream.isatty()`` and not ``json_output``.
    """
    stream = sys.stderr if stream is None else stream
    try:
        tty = bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or a closed stream
        tty = False
    return tty and not json_output


def close_all() -> None:
    """Close every bar still open: ``bikeid`` calls it when a command returns or fails, so an
    error line never lands on a half-drawn bar and handlers need no ``try``/``finally``."""
    for bar in list(_OPEN):
        bar.close()
