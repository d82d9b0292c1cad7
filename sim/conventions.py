"""State order, signal names and sign conventions, stated once for all of bikeid.

Signs follow Meijaard et al. (2007): x forward, y right, z down.  Roll phi > 0 is
a lean to the right, steer delta > 0 turns the front wheel to the right, yaw
psi > 0 turns the heading to the right, T_delta > 0 is a steer torque to the
right (rear frame on front frame), a lateral force F > 0 pushes to the right.
Angles are radians, rates rad/s, speeds m/s, torques N m, forces N.
"""

#: Linear-model state (sim.linear): q = [phi, delta] and its rate.
LINEAR_STATE = ("phi", "delta", "phidot", "deltadot")

#: Chen & Dao's canonical state order (ident.canonical).
CANONICAL_STATE = ("phi", "phidot", "delta", "deltadot")

#: Measured signals of Moore & Hubbard (2014) Table 1, in the order a controller
#: receives them (see :mod:`controllers`): speed, roll, steer, yaw, their rates and
#: the rear wheel rate.
MEASURED = ("v", "phi", "delta", "psi", "phidot", "deltadot", "psidot", "thetaRdot")

#: Inputs recorded with every run.
INPUTS = ("T_delta", "T_phi", "F")

#: Index of each measured channel in a measurement vector.
IDX = {name: i for i, name in enumerate(MEASURED)}

#: SI unit of every signal name (measured channels, inputs, pitch ``theta`` and the rear
#: (``x``, ``y``) and front (``xF``, ``yF``) contact coordinates).
UNITS = {
    "v": "m/s", "phi": "rad", "delta": "rad", "psi": "rad",
    "phidot": "rad/s", "deltadot": "rad/s", "psidot": "rad/s", "thetaRdot": "rad/s",
    "T_delta": "N m", "T_phi": "N m", "F": "N",
    "theta": "rad", "x": "m", "y": "m", "xF": "m", "yF": "m",
}  # fmt: skip
