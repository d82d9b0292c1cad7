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

#: Physical bounds of every bounded signal name: (lowest, highest) value a real or
#: simulated riderless bicycle can show, in the units of :data:`UNITS`.  A value outside is
#: a sensor or file fault, never data (``bikeid.dataset.run.check_plausible`` refuses it).
#: The bounds are deliberately loose (a factor of 4 or more above anything a bicycle that
#: stays in the model's domain does), so that they catch faults, not hard manoeuvres.
#: Names not listed (yaw ``psi`` and the contact coordinates ``x``, ``y``, ``xF``, ``yF``,
#: which accumulate without bound) are only checked for finiteness.
PLAUSIBLE = {
    # |roll| < pi/2: at a right angle the bicycle lies on the ground (the frame touches it
    # well before); the simulator stops at 60 deg (sim.integrate.DEFAULT_FALL_LIMIT).
    "phi": (-1.5707963267948966, 1.5707963267948966),
    # |steer| < pi/2: at a right angle the front wheel is crosswise and the benchmark's
    # contact geometry degenerates; real steering stops sit well inside (the measured
    # logs reach 0.93 rad).
    "delta": (-1.5707963267948966, 1.5707963267948966),
    # |roll rate| < 20 rad/s: a rigid bicycle toppling from upright reaches at the ground
    # omega = sqrt(2 m g h / I_xx) <= sqrt(2 g / h) (energy; I_xx >= m h^2 about the contact
    # line): 4.8 rad/s for the benchmark (h = 0.86 m), 5.9 rad/s for the riderless
    # steer-by-wire bicycle (h = 0.57 m); 20 rad/s is >= 3.4x both
    # (tests/dataset/test_plausibility.py
    # computes them).  The measured logs stay below 1.5 rad/s.
    "phidot": (-20.0, 20.0),
    # |steer rate| < 30 rad/s: fast human steering peaks near 10 rad/s; a free front
    # assembly turning through its +-pi/2 range in 0.1 s is ~30 rad/s.  (Logs: < 5.4 rad/s.)
    "deltadot": (-30.0, 30.0),
    # |yaw rate| < 20 rad/s: v tan(delta) cos(lambda) / w; bounded like the roll rate.
    "psidot": (-20.0, 20.0),
    # speed -0.5..30 m/s: the bikeid models ride forward below 30 m/s (108 km/h, beyond any
    # riderless test); a wheel encoder at rest reads slightly below zero (the TU Delft
    # sensor reads 1.066 v - 0.128, observed down to -0.007 m/s), hence -0.5, not 0.
    "v": (-0.5, 30.0),
    # |rear wheel rate| < 150 rad/s: 30 m/s on a 0.3 m wheel is 100 rad/s.
    "thetaRdot": (-150.0, 150.0),
    # |steer torque| < 200 N m: a strong rider's hands give ~50 N m at the bar, the
    # steer-by-wire motor command stays below 8 N m in the logs; x4 the first.
    "T_delta": (-200.0, 200.0),
    # |roll torque| < 500 N m: a rider's hip torque, ~ m g h of a tipping 50 kg body.
    "T_phi": (-500.0, 500.0),
    # |lateral force| < 2000 N: about twice a standing adult's weight (a hard push).
    "F": (-2000.0, 2000.0),
    # |pitch| < pi/2: the rear frame pitches by hundredths of a radian on flat ground.
    "theta": (-1.5707963267948966, 1.5707963267948966),
}

#: Speed range [m/s] of a run's nominal speed (``Run.meta["speed"]``): forward motion up to
#: the upper bound of ``PLAUSIBLE["v"]`` (every bikeid model needs v > 0).
NOMINAL_SPEED = (0.0, 30.0)

#: Sample periods [s] a bicycle logger produces: 0.1 ms (10 kHz, beyond any IMU or encoder
#: logger of a bicycle) to 0.1 s (10 Hz, below which the weave, up to ~1 Hz, and the caster
#: mode, ~10 1/s, are not resolved).  A period outside is a time column in the wrong unit
#: (ms read as s gives 10 s for a 100 Hz log), checked by ``bikeid.dataset.plausibility``.
SAMPLE_PERIOD = (1e-4, 0.1)

#: Largest forward speed any command accepts [m/s] (360 km/h: beyond any bicycle; the
#: linear model's v^2 K2 stays far from overflow).
MAX_SPEED = 100.0
