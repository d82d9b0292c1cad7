"""Studies on measured (and measured-format) logs; the pipeline itself is
:mod:`bikeid.ident.effects`.

- :mod:`.study`: Moore & Hubbard's model comparison on the measured logs (direct, per-speed
  PEM, grey-box, Whipple, Whipple + effects; ``bikeid measured study``), with its report and
  figures in :mod:`.study_plots`.
- :mod:`.report`: before/after report (``bikeid measured report``).
- :mod:`.effect_trials`: randomized undeclared-effect trials on the nonlinear plant
  (``bikeid measured trials``).
- :mod:`.blind_trials`: effect-selection trials on logs from an independent generator.
- :mod:`.injected_terms`: any term of the discovery's dictionary as a generalized torque of
  that generator's plant.
- :mod:`.discovery_scores`: how a discovery's kept terms score against an injected one.
"""
