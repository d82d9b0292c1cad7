"""The names of the method table for command-line choice lists, without importing it.

:mod:`bikeid.ident.methods` loads every estimator (scipy.optimize, control, numba), which
the quick commands' start-up must not pay for (``tests/experiments/cli/test_startup.py``).
:class:`MethodChoices` is an argparse ``choices`` value that reads
:func:`bikeid.ident.methods.names` (or the method names alone) on first use: when an
option is checked or a help text printed.  Give the argument a ``metavar``, or argparse
lists the choices (and imports the table) while the parser is built.
"""

from __future__ import annotations

from collections.abc import Iterator

__all__ = ["MethodChoices"]


class MethodChoices:
    """The table's names as an argparse ``choices`` value, read lazily.

    Parameters
    ----------
    presets : bool, optional
        Include the named presets (:data:`bikeid.ident.methods.PRESETS`; default True),
        else only the :data:`~bikeid.ident.methods.METHODS` keys.
    """

    def __init__(self, presets: bool = True) -> None:
        self.presets = presets

    def _names(self) -> tuple[str, ...]:
        from bikeid.ident import methods  # lazy: the table loads every estimator

        return methods.names() if self.presets else tuple(methods.METHODS)

    def __contains__(self, name: object) -> bool:
        return name in self._names()

    def __iter__(self) -> Iterator[str]:
        return iter(self._names())

    def __len__(self) -> int:
        return len(self._names())

    def __str__(self) -> str:
        return ",".join(self._names())

    def __repr__(self) -> str:
        return f"MethodChoices({', '.join(self._names())})"
