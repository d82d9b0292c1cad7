"""The testbed studies on simulated closed-loop data.

- :mod:`.sweep`: resumable, deterministic, parallel sweeps of closed-loop runs over speeds
  and seeds (``bikeid sweep``), and the stabilization table (``bikeid stabilization``).
- :mod:`.accuracy`: identification accuracy on the nonlinear closed-loop testbed
  (``bikeid accuracy``).
- :mod:`.coverage`: how often the identified intervals contain the exact truth
  (``bikeid coverage``).
- :mod:`.scenario`: :class:`Scenario`, the closed-loop experiment as a value, and the one
  builder of its runs.
- :mod:`.estimator`: :class:`Estimator`, any estimator (a method-table name with settings,
  a peer, a user's callable) behind one call.
- :mod:`.consistency`: consistency studies of any estimator over seeds and data lengths,
  with a computed verdict (``bikeid consistency``); figures in :mod:`.consistency_plots`.
- :mod:`.method_choices`: the method table's names, read on first use (``--help`` stays
  light).
"""
