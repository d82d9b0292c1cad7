"""Synthetic free decays of a known experiment model, for tests of the identification.

The decays imitate the measured ones (speeds, push sizes, sensor noise and the steer
encoder's quantization) but come from the linear experiment model itself, so a fit can be
checked against the truth it was drawn from.  (The trials on the nonlinear plant with a
hidden effect are :mod:`bikeid.experiments.measured.effect_trials`.)
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from bikeid.dataset.sbw_logs import SPEED_CALIBRATION
from bikeid.dataset.windows import Window
from bikeid.ident.effects.experiment_model import ExperimentModel

__all__ = ["synthetic_windows"]


def synthetic_windows(
    truth: ExperimentModel, speeds, per_speed: int = 6, noise: float = 0.01, seed: int = 0
) -> list[Window]:
    """Free decays simulated by ``truth`` (linear experiment model, 10 substeps per loop)
    from random initial states like the measured pushes (|phidot0| ~ 0.3-0.6 rad/s),
    1 s long; white noise (``noise`` rad/s on roll rate, noise/5 rad on angles) and the
    steer encoder's 0.000767 rad quantization added to what the "sensors" report.

    Parameters
    ----------
    truth : ExperimentModel
        The model the decays come from.
    speeds : iterable of float
        Treadmill speeds [m/s].
    per_speed : int, optional
        Decays per speed.
    noise : float, optional
        Roll-rate noise std [rad/s].
    seed : int, optional
        Generator seed.

    Returns
    -------
    list of Window
        Files named ``synthetic_<speed>mps``.
    """
    rng = np.random.default_rng(seed)
    a, b = SPEED_CALIBRATION
    clean = []
    for v in speeds:
        vs = a * v + b
        for _ in range(per_speed):
            sgn = rng.choice([-1.0, 1.0])
            x0 = np.array([rng.normal(0, 0.01), sgn * rng.uniform(0.0, 0.08),
                           sgn * rng.uniform(0.3, 0.6), sgn * rng.uniform(0.5, 1.5)])  # fmt: skip
            z = np.zeros(100)
            w = Window("synthetic", float(v), 0, z + x0[0], z + x0[1], z + x0[2], z + x0[3],
                       z + vs, z.copy(), np.zeros(20))  # fmt: skip
            clean.append(w)
    sims = truth.simulate(clean, nsub=10)
    out = []
    q = 0.000767
    for w, s in zip(clean, sims, strict=True):
        phi = s["phi"] + rng.normal(0, noise / 5, w.n)
        delta = np.round((s["delta"] + rng.normal(0, noise / 5, w.n)) / q) * q
        phidot = s["phidot"] + rng.normal(0, noise, w.n)
        deltadot = s["deltadot"] + rng.normal(0, noise * 3, w.n)
        out.append(replace(w, phi=phi, delta=delta, phidot=phidot, deltadot=deltadot,
                           file=f"synthetic_{w.speed:g}mps"))  # fmt: skip
    return out
