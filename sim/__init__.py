"""Stage 1, the plant: the Carvallo-Whipple bicycle, linear and nonlinear.

Conventions (Meijaard et al. 2007): x forward, y right, z down; roll phi, steer delta,
steer torque T_delta and lateral force F positive to the right; SI units (m, kg,
kg m^2, s, rad, N m, N).  Linear state order x = [phi, delta, phidot, deltadot].

Modules:

- :mod:`~bikeid.sim.errors`: the error types every stage raises (:class:`InputError`,
  :class:`UntrustworthyResult`) and the command line's exit codes.
- :mod:`~bikeid.sim.textformats`: strict JSON/YAML readers (no duplicate keys, no NaN,
  bounded nesting) for every file a user passes.
- :mod:`~bikeid.sim.conventions`: state orders, signal names, units and sign conventions,
  stated once for all of bikeid.
- :mod:`~bikeid.sim.parameters`: :class:`BicycleParameters` in Meijaard notation
  (validated) and the bicycles by name (benchmark, steer-by-wire, ``bicycleparameters``
  bicycles, YAML/JSON files).
- :mod:`~bikeid.sim.linear`: the linearized model M, C1, K0, K2 (Meijaard 2007, App. A),
  state-space and transfer-function forms, eigenvalues against speed, critical speeds.
- :mod:`~bikeid.sim.nonlinear`: the nonlinear Whipple bicycle in Moore (2012) coordinates
  (:class:`WhippleBicycle`), built on the generated equations.
- :mod:`~bikeid.sim.integrate`: fixed-step (RK4, numba) and reference (DOP853) simulation
  of the nonlinear bicycle under a sampled controller (:func:`simulate`).
- :mod:`~bikeid.sim.effects`: optional physical effects the Whipple model lacks (steer
  friction, actuator lag, ...), injected by the simulator.
- :mod:`~bikeid.sim.effect_registry`: every such effect declared once (name, unit,
  plausible range, layer, its law, how the plant carries it).
- :mod:`~bikeid.sim.effect_law`: the small language of effect laws (which equation, which
  term, its unit), shared by the registry, user files and discovery.
- :mod:`~bikeid.sim.effect_files`: a user's effects declared in a YAML or JSON file.
- :mod:`~bikeid.sim.blas`: one BLAS thread for the small-matrix numerics (a context and
  a decorator), unless the user set a thread count.
- :mod:`~bikeid.sim.sampling`: the one exact zero-order-hold discretization (:func:`zoh`).
- :mod:`~bikeid.sim.periodic_orbits`: periodic orbits of the uncontrolled bicycle converged
  on a Poincare map, and their Floquet multipliers.
- :mod:`~bikeid.sim.arm_model`: the arm model (the linearized Whipple bicycle plus the
  rider's arms, Moore & Hubbard) as M, C1, K0, K2, and its stable speed ranges.
- ``_whipple_generated``: the equations of motion emitted by ``scripts/derive_whipple.py``
  (private); ``_arms_generated``: the arm model's pieces emitted by ``scripts/derive_arms.py``
  (private).

Nothing is imported here, so ``import bikeid.sim`` stays cheap; import the modules.
"""
