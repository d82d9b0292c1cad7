"""Stage 5, the experiments: the ``bikeid`` command line, paper reproductions and reports.

Modules:

- :mod:`~bikeid.experiments.cli`: the ``bikeid`` command line (entry point); each group of
  subcommands lives in a ``cmd_*`` module:
  :mod:`~bikeid.experiments.cmd_plant` (``eig``, ``linearize``, ``critical-speeds``),
  :mod:`~bikeid.experiments.cmd_simulate` (``simulate``),
  :mod:`~bikeid.experiments.cmd_data` (``sweep``, ``stabilization``),
  :mod:`~bikeid.experiments.cmd_ident` (``identify``, ``accuracy``),
  :mod:`~bikeid.experiments.cmd_validate` (``validate``),
  :mod:`~bikeid.experiments.cmd_reproduce` (``reproduce``),
  :mod:`~bikeid.experiments.cmd_measured` (``measured fit|evaluate|report|trials|study``,
  ``data fetch``), :mod:`~bikeid.experiments.cmd_coverage` (``coverage``).
- :mod:`~bikeid.experiments.progress`: progress bars of the long commands (stderr, only on a
  terminal and without ``--json``); library loops report through a callback.
- :mod:`~bikeid.experiments.cliutil`: helpers shared by the command modules (ranges, JSON
  output, bicycles).
- :mod:`~bikeid.experiments.sweep`: resumable, deterministic, parallel sweeps of
  closed-loop runs over speeds and seeds.
- :mod:`~bikeid.experiments.accuracy`: identification accuracy on the nonlinear closed-loop
  testbed (``bikeid accuracy``).
- :mod:`~bikeid.experiments.reproduce`: both papers redone (``bikeid reproduce``), built on
  :mod:`~bikeid.experiments.reproduce_chen_dao` (Chen & Dao 2010, Figs. 2-5, 7, eqs. 5-6;
  numerics) with its figures in :mod:`~bikeid.experiments.reproduce_chen_dao_figures`,
  and :mod:`~bikeid.experiments.reproduce_moore_hubbard` (Moore & Hubbard, Tables 2-5,
  Figs. 2-4 analogues); :mod:`~bikeid.experiments.reproduce_report` renders the Markdown
  report.
- :mod:`~bikeid.experiments.limit_cycles`: Chen & Dao Figs. 4-5, uncontrolled coasting at
  3.5 m/s and whether the motion is periodic; :mod:`~bikeid.experiments.floquet` converges
  a periodic orbit on the Poincare map and computes its Floquet multipliers.
- :mod:`~bikeid.experiments.blind_trials`: effect-selection trials on logs from an
  independent generator with randomized nuisances (four rates a user suffers).
- :mod:`~bikeid.experiments.effect_trials`: randomized undeclared-effect trials on the
  nonlinear plant (``bikeid measured trials``).
- :mod:`~bikeid.experiments.measured_study`: the measured-data pipeline as a library
  (fit a model with the effect library, save/load it, evaluate it on held-out decays).
- :mod:`~bikeid.experiments.measured_report`: before/after report on the measured data
  (``bikeid measured report``).
- :mod:`~bikeid.experiments.real_study`: Moore & Hubbard's model comparison on the measured
  logs (direct, per-speed PEM, grey-box, Whipple, Whipple + effects; held-out VAF tables and
  the effect translation of identified entries; ``bikeid measured study``), with its report
  and figures in :mod:`~bikeid.experiments.real_study_plots`.
- :mod:`~bikeid.experiments.coverage`: how often PEM's intervals contain the exact truth on
  the linear plant (``bikeid coverage``).
- :mod:`~bikeid.experiments.report`: Markdown reports (paper | identified | truth tables)
  and ``summary.json``.
- :mod:`~bikeid.experiments.plots`: Matplotlib figures shared by commands and reports.
- :mod:`~bikeid.experiments.validation_plots`: the compare, resid and Bode figures of
  ``bikeid validate``.

Nothing is imported here; import the modules.
"""
