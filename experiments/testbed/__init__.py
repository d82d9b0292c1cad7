"""The testbed studies on simulated closed-loop data.

- :mod:`.sweep`: resumable, deterministic, parallel sweeps of closed-loop runs over speeds
  and seeds (``bikeid sweep``), and the stabilization table (``bikeid stabilization``).
- :mod:`.accuracy`: identification accuracy on the nonlinear closed-loop testbed
  (``bikeid accuracy``).
- :mod:`.coverage`: how often the identified intervals contain the exact truth
  (``bikeid coverage``).
"""
