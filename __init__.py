"""bikeid: the nonlinear Carvallo-Whipple bicycle and its closed-loop identification.

The package is five stages; data flows one way and a later stage imports earlier
ones only (``tests/test_layers.py`` enforces it):

``bikeid.sim``
    Parameters (Meijaard 2007 notation), the linear benchmark model
    (``linear.state_space`` -> ``control.StateSpace``, ``linear.critical_speeds``),
    the nonlinear plant, the integrator and the effect registry.
``bikeid.controllers``
    Roll-angle controllers (``make("pid" | "pole-placement" | "fuzzy" |
    "steer-into-lean", p)``), references and dither.
``bikeid.dataset``
    ``Run`` (the time-series type), the closed-loop engines (``closed_loop.simulate_run``
    for the nonlinear plant, ``linear_loop.simulate`` for the exact linear one),
    sensors, the HDF5 store and the measured-data loaders.
``bikeid.ident``
    Moore & Hubbard's direct least squares (``ident.identify``), Chen & Dao's
    canonical PEM (``ident.fit``, ``ident.fit_speed_model``), validation
    (``ident.validate.compare``, ``ident.validate.resid``) and the effect-library
    discrepancy analysis of measured data.
``bikeid.experiments``
    The ``bikeid`` command line, sweeps, accuracy tables and the reproductions of
    both papers.

Conventions (state order, signal names, units, signs) are stated once in
``bikeid.sim.conventions``: SI units, radians, Meijaard 2007 axes (x forward,
y right, z down; roll, steer and steer torque positive to the right).
"""

import _signal as _sig  # the C module: already loaded, so this costs nothing
import sys as _sys

__all__ = ["__version__"]


def _interrupted_while_starting(signum, frame):  # noqa: ARG001 - a signal handler
    """Ctrl-C while the ``bikeid`` command imports its modules: one line, exit status 130
    (:func:`bikeid.experiments.cli.main` restores Python's handler when it starts)."""
    _sys.stderr.write("bikeid: interrupted\n")
    raise SystemExit(130)


if (
    _sys.argv
    and _sys.argv[0].rsplit("/", 1)[-1] in ("bikeid", "-m")  # the console script, python -m
    and _sig.getsignal(_sig.SIGINT) is _sig.default_int_handler
):
    _sig.signal(_sig.SIGINT, _interrupted_while_starting)


def __getattr__(name: str) -> str:
    """``bikeid.__version__``, read from the installed metadata on first use
    (``importlib.metadata`` costs ~30 ms of every command's start-up otherwise).

    Parameters
    ----------
    name : str
        The attribute asked for.

    Returns
    -------
    str
        The installed version, or ``"0+unknown"`` in a source tree that is not installed.

    Raises
    ------
    AttributeError
        For any other name.
    """
    if name != "__version__":
        raise AttributeError(f"module 'bikeid' has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("bikeid")
    except PackageNotFoundError:  # imported from a source tree that is not installed
        return "0+unknown"
