"""Stage 3, the data: experiment runs, simulated in closed loop or measured, and their files.

Simulated and measured data both become a :class:`~bikeid.dataset.run.Run` with the
signals of :mod:`bikeid.sim.conventions` (SI units, Meijaard signs), so identification
never knows where the data came from.

Modules:

- :mod:`~bikeid.dataset.run`: :class:`Run`, one experiment's time series plus metadata, and
  the data object a user builds (``Run.from_arrays``, ``Run.from_dataframe``,
  ``Run.from_timeresponse``) with its units, sample time and physical ranges checked.
- :mod:`~bikeid.dataset.tabular`: what every reader shares before a run is built (the table
  of columns read, the mapping arguments' checks).
- :mod:`~bikeid.dataset.units`: the one table of units and their factors to SI, and the
  parser of a unit or a value with a unit (case-insensitive where unambiguous).
- :mod:`~bikeid.dataset.closed_loop`: closed-loop runs on the nonlinear plant (controller,
  reference, dither, sensors, effects) -> :class:`Run`.
- :mod:`~bikeid.dataset.linear_loop`: the exact (zero-order-hold) closed loop of the linear
  bicycle with the same controllers -> :class:`Run`, where every identified quantity is known
  exactly.
- :mod:`~bikeid.dataset.sensors`: sensor models (scale, low-pass, bias, noise,
  quantization of each channel).
- :mod:`~bikeid.dataset.sbw_logs`: parser of the TU Delft steer-by-wire treadmill logs
  (``tudelft-sbw``), despiking, the treadmill speed calibration.
- :mod:`~bikeid.dataset.decays`: free-decay segments of those logs (transcribed or detected
  from the roll rate).
- :mod:`~bikeid.dataset.windows`: :class:`Window`, one free decay or Bode record cut from a
  run, with its measured initial state and command history.
- :mod:`~bikeid.dataset.download`: fetching the measured data from its upstream repository
  at a pinned commit, checksummed.
- :mod:`~bikeid.dataset.store`: runs on disk (HDF5, one group per run) and CSV export.
- :mod:`~bikeid.dataset.importers`: a user's own logs (CSV, any HDF5 file) -> :class:`Run`,
  with a column mapping, unit conversion, sign flips and checked data.
- :mod:`~bikeid.dataset.files`: safe atomic file writing used by every output of bikeid.
- :mod:`~bikeid.dataset.plausibility`: checks of a run's units and signs before any fit
  (sample period, each rate against its angle's derivative).
- :mod:`~bikeid.dataset.signs`: the relative signs of roll, steer and torque checked against
  a nominal bicycle's equations of motion (a mirrored axis).
- :mod:`~bikeid.dataset.check_names`: the names of the checks a caller may skip.
- :mod:`~bikeid.dataset.logs`: the one loader: :class:`LogOptions` (format, columns, units,
  signs, window, speed split, checks, bicycle) and ``load_runs``, every check applied, for
  the command line and the Python API alike.

Nothing is imported here; import the modules.
"""
