"""The nominal bicycle's measurement uncertainty, and the nominal calibrated within it.

A measured bicycle's parameters carry an uncertainty: inertias from pendulum swings, trail
from a ruler.  A nominal model off by that much does not fit free decays to their noise, and
without a place for that mismatch the effect selection reads it as a physical effect (on the
blind trials: a steer damping of 0.02 N m s/rad, a 2 ms input delay, a rear-frame inertia
2 % off).  This module gives the mismatch its place:

- :class:`NominalUncertainty` states the uncertain parameters and their half-widths: each
  body's inertia tensor (rear wheel R, rear frame B, front frame H, front wheel F) scaled by
  one factor within +-``inertia`` (relative; one factor per body keeps the tensor physical),
  and the trail within +-``trail`` [m].  The defaults, +-5 % and +-2 mm, are what we use where
  no uncertainty is published (the steer-by-wire bicycle's data give none).
- :class:`Calibration` is a point in that box: offsets x in [-1, 1]^k, x = +-1 the band's
  edges, applied to the stated parameters.  The effect fits (:func:`bikeid.ident.effects.fit.
  fit_effects` with ``calibration=``) move x within the box together with the effects, by
  bounded least squares on the same output error: a uniform prior over the band, not a
  penalty whose weight would need the noise level.
- :meth:`NominalUncertainty.excess` is how far a library *parameter* correction
  (``trail_correction``, ``front_inertia_scale``, ``rear_inertia_scale``) reaches beyond the
  band: a parameter off by no more than its uncertainty is not an effect
  (:func:`bikeid.ident.effects.selection.select_effects` tests its t from the band's edge).
- The instruments' offsets get bands too (``sensor``): a gyro bias ``roll_rate_bias``, a
  roll-angle offset ``roll_angle_bias`` and an encoder zero ``steer_angle_bias`` within them
  are the instrument's stated uncertainty, not findings, so they are tested beyond the band
  the same way (they are fitted as library effects, not calibrated as offsets).  Defaults,
  our assumption where the data give no specification: +-0.01 rad/s (0.6 deg/s, the order of
  a MEMS gyro's offset left after zeroing at standstill), +-0.005 rad (0.3 deg, IMU levelling)
  and +-0.002 rad (0.1 deg, an encoder zeroed on a straight wheel).

Only the parameters named here move; masses, geometry other than the trail, and the
controller are taken as stated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from bikeid.sim.parameters import BicycleParameters

__all__ = ["BODY_INERTIAS", "DEFAULT_TEXT", "SENSOR_BANDS", "Calibration", "NominalUncertainty"]

#: The inertia entries of each body [kg m^2], scaled together by one factor.
BODY_INERTIAS: dict[str, tuple[str, ...]] = {
    "R": ("IRxx", "IRyy"),
    "B": ("IBxx", "IByy", "IBzz", "IBxz"),
    "H": ("IHxx", "IHyy", "IHzz", "IHxz"),
    "F": ("IFxx", "IFyy"),
}
#: Library parameter corrections along a calibrated direction: effect -> offset name.
_OVERLAPS = {"trail_correction": "trail", "front_inertia_scale": "inertia_H",
             "rear_inertia_scale": "inertia_B"}  # fmt: skip
#: Default half-widths of the instruments' offsets, by library effect [its unit].
SENSOR_BANDS = {"roll_rate_bias": 0.01, "roll_angle_bias": 0.005, "steer_angle_bias": 0.002}
#: The text of the default uncertainty (``bikeid measured fit --nominal-uncertainty``).
DEFAULT_TEXT = "inertia=0.05,trail=0.002," + ",".join(f"{k}={v:g}" for k, v in SENSOR_BANDS.items())


@dataclass(frozen=True)
class NominalUncertainty:
    """Half-widths of the nominal parameters' uncertainty.

    Attributes
    ----------
    inertia : float
        Relative half-width of each body's inertia scale (0.05: every body's tensor within
        x0.95-1.05); 0 keeps the inertias as stated.
    trail : float
        Half-width of the trail [m]; 0 keeps it as stated.
    sensor : dict of str to float
        Half-widths of the instruments' offsets by library effect (``roll_rate_bias``
        [rad/s], ``roll_angle_bias`` [rad], ``steer_angle_bias`` [rad]); default
        :data:`SENSOR_BANDS`, a name left out has none.

    Raises
    ------
    ValueError
        If a half-width is not a finite number, ``inertia`` is outside [0, 0.5), ``trail``
        outside [0, 0.05) m, a sensor band is not one of :data:`SENSOR_BANDS`' names or
        outside [0, its plausible range).
    """

    inertia: float = 0.05
    trail: float = 0.002
    sensor: dict = field(default_factory=lambda: dict(SENSOR_BANDS))

    def __post_init__(self) -> None:
        checks = [("inertia", self.inertia, 0.5, "relative"), ("trail", self.trail, 0.05, "m")]
        for name, v in self.sensor.items():
            if name not in SENSOR_BANDS:
                raise ValueError(f"nominal uncertainty: {name!r} is not an instrument offset; "
                                 f"use {', '.join(SENSOR_BANDS)}")  # fmt: skip
            checks.append((name, v, 0.2, "its unit"))
        for name, v, hi, unit in checks:
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 <= v < hi):
                raise ValueError(f"nominal uncertainty {name} must be a number in [0, {hi}) "
                                 f"({unit} half-width), got {v!r}")  # fmt: skip

    @property
    def names(self) -> tuple[str, ...]:
        """The calibrated offsets, in order: ``inertia_R``, ``inertia_B``, ``inertia_H``,
        ``inertia_F`` (when ``inertia`` > 0), ``trail`` (when ``trail`` > 0)."""
        out = tuple(f"inertia_{b}" for b in BODY_INERTIAS) if self.inertia > 0 else ()
        return out + (("trail",) if self.trail > 0 else ())

    def width(self, name: str) -> float:
        """Half-width of one offset.

        Parameters
        ----------
        name : str
            One of :attr:`names`.

        Returns
        -------
        float
            Relative for an inertia, [m] for the trail.
        """
        return self.trail if name == "trail" else self.inertia

    def apply(self, p: BicycleParameters, x: np.ndarray) -> BicycleParameters:
        """The parameters ``p`` moved to the offsets ``x``.

        Parameters
        ----------
        p : BicycleParameters
            The stated (nominal) parameters.
        x : ndarray
            Offsets in units of the half-widths, in the order of :attr:`names` (+-1: the
            band's edges).

        Returns
        -------
        BicycleParameters
            Each body's inertia tensor times 1 + inertia x_body, trail c + trail x_trail.
        """
        ch: dict[str, float] = {}
        for name, xi in zip(self.names, np.asarray(x, dtype=float), strict=True):
            if name == "trail":
                ch["c"] = p.c + self.trail * xi
            else:
                s = 1.0 + self.inertia * xi
                ch.update({k: s * getattr(p, k) for k in BODY_INERTIAS[name[-1]]})
        return p.replace(**ch) if ch else p

    def values(self, x: np.ndarray) -> dict[str, float]:
        """The offsets in physical units.

        Parameters
        ----------
        x : ndarray
            Offsets in half-widths (order of :attr:`names`).

        Returns
        -------
        dict of str to float
            Relative inertia change [-] per body, trail change [m].
        """
        return {n: self.width(n) * float(xi) for n, xi in zip(self.names, x, strict=True)}

    def excess(self, effect: str, value: float, x: np.ndarray) -> float | None:
        """How far a library parameter correction reaches beyond the band [effect unit].

        The correction stacks on the calibrated offset along the same direction; only the
        part of the total beyond the half-width is evidence of an effect.

        Parameters
        ----------
        effect : str
            Registry name.
        value : float
            The correction [its unit]: trail [m] or an inertia scale [-].
        x : ndarray
            The calibrated offsets (order of :attr:`names`).

        Returns
        -------
        float or None
            max(|total deviation| - half-width, 0) [m or relative; for an instrument offset
            max(|value| - its band, 0) in its unit]; None when ``effect`` has no band.
        """
        if effect in self.sensor:
            return max(abs(value) - self.sensor[effect], 0.0)
        name = _OVERLAPS.get(effect)
        if name not in self.names:
            return None
        off = self.values(x)[name]
        total = off + value if name == "trail" else (1.0 + off) * value - 1.0
        return max(abs(total) - self.width(name), 0.0)

    def as_dict(self) -> dict:
        """The half-widths, JSON-ready.

        Returns
        -------
        dict
            ``inertia`` (relative), ``trail`` [m] and ``sensor`` (by effect, its unit).
        """
        return {"inertia": self.inertia, "trail": self.trail, "sensor": dict(self.sensor)}

    @classmethod
    def parse(cls, text: str) -> NominalUncertainty | None:
        """An uncertainty from text: ``none``, ``default`` or ``inertia=F,trail=M``.

        Parameters
        ----------
        text : str
            ``none`` (the stated parameters are exact: no calibration), ``default``
            (:data:`DEFAULT_TEXT`), or comma-separated ``inertia=`` (relative), ``trail=``
            [m] and instrument-offset (``roll_rate_bias=`` ...) half-widths (an omitted one
            is 0).

        Returns
        -------
        NominalUncertainty or None
            None for ``none``.

        Raises
        ------
        ValueError
            Naming the bad part and the accepted forms.
        """
        t = text.strip().lower()
        if t == "none":
            return None
        if t == "default":
            t = DEFAULT_TEXT
        kw: dict[str, float] = {}
        for part in t.split(","):
            key, sep, val = part.partition("=")
            key = key.strip()
            try:
                if not sep or key not in ("inertia", "trail", *SENSOR_BANDS) or key in kw:
                    raise ValueError
                kw[key] = float(val)
            except ValueError:
                raise ValueError(
                    f"nominal uncertainty {text!r}: cannot read {part!r}; use none, default "
                    f"or inertia=F,trail=M[,roll_rate_bias=B,...] (half-widths: relative, "
                    f"metres, the offset's unit; the default is {DEFAULT_TEXT})"
                ) from None
        sensor = {k: kw[k] for k in SENSOR_BANDS if k in kw}
        return cls(kw.get("inertia", 0.0), kw.get("trail", 0.0), sensor)


@dataclass(frozen=True)
class Calibration:
    """A point of the nominal uncertainty's box, and the stated parameters it moves.

    Attributes
    ----------
    uncertainty : NominalUncertainty
        The box.
    base : BicycleParameters
        The stated parameters (offset 0).
    offsets : ndarray
        Offsets in units of the half-widths (order of ``uncertainty.names``), in [-1, 1];
        empty (default): all 0.  A ValueError names a count that does not match.
    std : ndarray or None
        Their standard errors from the fit that set them (same units; 0 for an offset held
        on the box's edge), None before a fit.
    """

    uncertainty: NominalUncertainty
    base: BicycleParameters
    offsets: np.ndarray = field(default_factory=lambda: np.zeros(0))
    std: np.ndarray | None = None

    def __post_init__(self) -> None:
        k = len(self.uncertainty.names)
        if self.offsets.size == 0 and k:  # not given: the stated parameters
            object.__setattr__(self, "offsets", np.zeros(k))
        elif self.offsets.size != k:
            raise ValueError(f"calibration offsets: {self.offsets.size} given, the uncertainty "
                             f"has {k} ({', '.join(self.uncertainty.names)})")  # fmt: skip

    def params(self, x: np.ndarray | None = None) -> BicycleParameters:
        """The parameters at some offsets.

        Parameters
        ----------
        x : ndarray, optional
            Offsets in half-widths (default: :attr:`offsets`).

        Returns
        -------
        BicycleParameters
            :meth:`NominalUncertainty.apply` of :attr:`base`.
        """
        return self.uncertainty.apply(self.base, self.offsets if x is None else x)

    def excess(self, effect: str, value: float) -> float | None:
        """How far a correction reaches beyond its band at these offsets.

        Parameters
        ----------
        effect : str
            Registry name.
        value : float
            The correction [its unit].

        Returns
        -------
        float or None
            :meth:`NominalUncertainty.excess` at :attr:`offsets`.
        """
        return self.uncertainty.excess(effect, value, self.offsets)

    def as_dict(self) -> dict:
        """The calibration as a JSON-ready record.

        Returns
        -------
        dict
            ``uncertainty`` (the half-widths), ``offsets`` in physical units (relative
            inertia change, trail [m]), ``at_edge`` (offsets within 1 % of the band's edge)
            and, after a fit, ``std`` (same units).
        """
        vals = self.uncertainty.values(self.offsets)
        out = {"uncertainty": self.uncertainty.as_dict(), "offsets": vals,
               "at_edge": [n for n, xi in zip(self.uncertainty.names, self.offsets,
                                              strict=True) if abs(xi) > 0.99]}  # fmt: skip
        if self.std is not None:
            out["std"] = self.uncertainty.values(self.std)
        return out
