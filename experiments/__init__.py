"""Stage 5, the experiments, by role:

- :mod:`bikeid.experiments.cli`: the ``bikeid`` command line (entry point ``main``, also
  ``python -m bikeid``); one module per command group (``plant``, ``simulate``, ``data``,
  ``identify``, ``validate``, ``reproduce``, ``measured``, ``coverage``) and the argument
  helpers in ``args``.
- :mod:`bikeid.experiments.testbed`: studies on simulated closed-loop data (sweeps,
  stabilization, accuracy, coverage).
- :mod:`bikeid.experiments.papers`: the reproductions of Moore & Hubbard and Chen & Dao.
- :mod:`bikeid.experiments.measured`: the studies on measured logs.

Rendering shared by all of them: :mod:`bikeid.experiments.report` (Markdown tables and
``summary.json``), :mod:`bikeid.experiments.plots` and
:mod:`bikeid.experiments.validation_plots` (matplotlib figures);
:mod:`bikeid.experiments.progress` shows progress of long work;
:mod:`bikeid.experiments.parallel` runs the many independent jobs of a study (local
processes or a Dask cluster, the same numbers either way).

Nothing is imported here; import the modules.
"""
