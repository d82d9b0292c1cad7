"""Stage 3, the data: experiment runs, simulated in closed loop or measured, and their files.

Simulated and measured data both become a :class:`~bikeid.dataset.run.Run` with the
signals of :mod:`bikeid.sim.conventions` (SI units, Meijaard signs), so identification
never knows where the data came from.

Modules:

- :mod:`~bikeid.dataset.run`: :class:`Run`, one experiment's time series plus metadata.
- :mod:`~bikeid.dataset.closed_loop`: closed-loop runs on the nonlinear plant (controller,
  reference, dither, sensors, effects) -> :class:`Run`.
- :mod:`~bikeid.dataset.sensors`: sensor models (scale, low-pass, bias, noise,
  quantization of each channel).
- :mod:`~bikeid.dataset.measured`: loader for the TU Delft steer-by-wire treadmill logs
  (``tudelft-sbw``).
- :mod:`~bikeid.dataset.store`: runs on disk (HDF5, one group per run) and CSV export.
- :mod:`~bikeid.dataset.files`: safe atomic file writing used by every output of bikeid.

Nothing is imported here; import the modules.
"""
