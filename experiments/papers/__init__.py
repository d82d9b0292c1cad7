"""The paper reproductions (``bikeid reproduce``).

- :mod:`.reproduce`: both papers redone, figures, ``report.md`` and ``summary.json``.
- :mod:`.chen_dao`: Chen & Dao 2010 (Figs. 2-5, 7, eqs. 5-6), numerics; its figures in
  :mod:`.chen_dao_figures`.
- :mod:`.moore_hubbard`: Moore & Hubbard (Tables 2-5, Figs. 2-4 analogues).
- :mod:`.limit_cycles`: uncontrolled coasting near 3.5 m/s (Chen & Dao Figs. 4-5) and
  whether the motion is periodic (orbits and multipliers: :mod:`bikeid.sim.periodic_orbits`).
- :mod:`.orbit_convergence`: whether a periodic or growing coasting run ends near a periodic
  orbit (Newton on the Poincare map from the run's end) and the orbit's family.
- :mod:`.verdicts`: the report's verdict table, one line per claim, computed from data.
- :mod:`.report`: the Markdown report of the reproduction.
"""
