"""Bicycle parameter sets in Meijaard et al. (2007) benchmark notation.

Axes (Meijaard 2007): x forward, y to the right, z down, origin at the rear
contact point in the upright reference configuration, so a mass centre above
the ground has a *negative* z.  SI units throughout: m, kg, kg m^2, rad, m/s^2.

:class:`BicycleParameters` is immutable and validated on construction.  Build
one with :func:`benchmark` (the exact Table 1 values), :func:`from_bicycleparameters`
(a bicycle shipped with the ``bicycleparameters`` package), :func:`steer_by_wire`
(the TU Delft steer-by-wire bicycle of the measured data), :func:`from_file`
(a user's YAML or JSON file) or :func:`by_name`, which dispatches on a name.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from .errors import InputError
from .textformats import loads_json, loads_yaml

__all__ = [
    "BicycleParameters",
    "benchmark",
    "by_name",
    "from_bicycleparameters",
    "from_file",
    "known_names",
    "steer_by_wire",
]

#: Parameter names, units and meaning (Meijaard 2007, Table 1 order).
PARAMETER_DOC: dict[str, tuple[str, str]] = {
    "w": ("m", "wheelbase"),
    "c": ("m", "trail"),
    "lam": ("rad", "steer axis tilt from vertical"),
    "g": ("m/s^2", "gravitational acceleration"),
    "rR": ("m", "rear wheel radius"),
    "mR": ("kg", "rear wheel mass"),
    "IRxx": ("kg m^2", "rear wheel diametral inertia (= IRzz)"),
    "IRyy": ("kg m^2", "rear wheel spin inertia"),
    "xB": ("m", "rear body mass centre, x"),
    "zB": ("m", "rear body mass centre, z (negative above ground)"),
    "mB": ("kg", "rear body mass"),
    "IBxx": ("kg m^2", "rear body inertia xx about its mass centre"),
    "IByy": ("kg m^2", "rear body inertia yy"),
    "IBzz": ("kg m^2", "rear body inertia zz"),
    "IBxz": ("kg m^2", "rear body product of inertia xz"),
    "xH": ("m", "front frame mass centre, x"),
    "zH": ("m", "front frame mass centre, z (negative above ground)"),
    "mH": ("kg", "front frame mass"),
    "IHxx": ("kg m^2", "front frame inertia xx about its mass centre"),
    "IHyy": ("kg m^2", "front frame inertia yy"),
    "IHzz": ("kg m^2", "front frame inertia zz"),
    "IHxz": ("kg m^2", "front frame product of inertia xz"),
    "rF": ("m", "front wheel radius"),
    "mF": ("kg", "front wheel mass"),
    "IFxx": ("kg m^2", "front wheel diametral inertia (= IFzz)"),
    "IFyy": ("kg m^2", "front wheel spin inertia"),
}

#: Plausible magnitude of each kind of parameter: |value| below this (SI).  Beyond it a
#: value is a typo or a unit slip (mm for m, g for kg), and e.g. ``mB: 1e308`` would print
#: "none below 30 m/s" instead of an error.
PLAUSIBLE_LIMIT: dict[str, float] = {"m": 10.0, "kg": 1000.0, "kg m^2": 1000.0, "m/s^2": 100.0}


@dataclass(frozen=True)
class BicycleParameters:
    """Whipple bicycle parameters, Meijaard (2007) notation (see module docstring).

    Construction validates every value and raises :class:`ValueError` naming the
    parameter and the rule it breaks.  Use :meth:`replace` to derive a variant.
    Every numerical value is converted to ``float``.  Axes: x forward, y right,
    z down, origin at the rear contact point; a mass centre above the ground has
    a negative z.  The wheels are axisymmetric: IRzz = IRxx and IFzz = IFxx are implied.

    Parameters
    ----------
    w : float
        Wheelbase [m], > 0.
    c : float
        Trail [m], |c| < w.
    lam : float
        Steer axis tilt from vertical [rad], in (-pi/2, pi/2).
    g : float
        Gravitational acceleration [m/s^2], > 0.
    rR : float
        Rear wheel radius [m], > 0.
    mR : float
        Rear wheel mass [kg], > 0.
    IRxx : float
        Rear wheel diametral inertia (= IRzz) [kg m^2], > 0.
    IRyy : float
        Rear wheel spin inertia [kg m^2], in (0, 2 IRxx].
    xB, zB : float
        Rear body (frame and rider) mass centre [m]; zB < 0.
    mB : float
        Rear body mass [kg], > 0.
    IBxx, IByy, IBzz, IBxz : float
        Rear body inertia about its mass centre, benchmark axes [kg m^2]; the tensor
        must be positive definite and its principal moments obey the triangle
        inequality.
    xH, zH : float
        Front frame (fork and handlebar) mass centre [m]; zH < 0.
    mH : float
        Front frame mass [kg], > 0.
    IHxx, IHyy, IHzz, IHxz : float
        Front frame inertia about its mass centre, benchmark axes [kg m^2]; same
        rules as the rear body.
    rF : float
        Front wheel radius [m], > 0.
    mF : float
        Front wheel mass [kg], > 0.
    IFxx : float
        Front wheel diametral inertia (= IFzz) [kg m^2], > 0.
    IFyy : float
        Front wheel spin inertia [kg m^2], in (0, 2 IFxx].
    name : str, optional
        Label of the bicycle. Default "custom".

    Raises
    ------
    bikeid.sim.errors.InputError
        A ValueError: if a value is not a finite real number (booleans and text are
        refused), lies outside its plausible range (:data:`PLAUSIBLE_LIMIT`: lengths
        below 10 m, masses below 1000 kg, inertias below 1000 kg m^2, g below 100 m/s^2)
        or breaks a physical rule (the message names the parameter and the rule).

    See Also
    --------
    PARAMETER_DOC : Units and meaning of every parameter.
    """

    w: float
    c: float
    lam: float
    g: float
    rR: float
    mR: float
    IRxx: float
    IRyy: float
    xB: float
    zB: float
    mB: float
    IBxx: float
    IByy: float
    IBzz: float
    IBxz: float
    xH: float
    zH: float
    mH: float
    IHxx: float
    IHyy: float
    IHzz: float
    IHxz: float
    rF: float
    mF: float
    IFxx: float
    IFyy: float
    name: str = "custom"

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "name":
                continue
            value = getattr(self, f.name)
            if isinstance(value, (bool, np.bool_)) or not isinstance(
                value, (int, float, np.integer, np.floating)
            ):
                raise InputError(
                    f"parameter {f.name!r} must be a real number [{PARAMETER_DOC[f.name][0]}], "
                    f"got {_show(value)}"
                )
            try:
                fvalue = float(value)
            except OverflowError:  # an int beyond float
                fvalue = math.inf
            if not math.isfinite(fvalue):
                raise InputError(
                    f"parameter {f.name!r} is {fvalue}: every parameter must be finite"
                )
            object.__setattr__(self, f.name, fvalue)
        _validate(self)

    # -- conversions -----------------------------------------------------------------
    def as_dict(self) -> dict[str, float]:
        """The numerical parameters as a plain dict.

        Returns
        -------
        dict of str to float
            ``{parameter: value}`` in SI units, field order (Meijaard 2007 Table 1
            order); the ``name`` label is not included.
        """
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "name"}

    def replace(self, **changes: Any) -> BicycleParameters:
        """A validated copy with some values changed.

        Parameters
        ----------
        **changes : float or str
            New values by field name (SI units), e.g. ``c=0.1``; ``name`` relabels.

        Returns
        -------
        BicycleParameters
            The copy (``dataclasses.replace``), validated on construction.

        Raises
        ------
        ValueError
            If a new value breaks a rule (see :class:`BicycleParameters`).
        TypeError
            If a keyword is not a field name.
        """
        return dataclasses.replace(self, **changes)

    def to_moore(self) -> dict[str, float]:
        """Moore (2012) parameters used by the nonlinear model.

        Formulas as in DynamicistToolKit ``benchmark_to_moore``: d1, d2, d3 are the
        rear offset, steer-axis length and fork offset; l1..l4 locate the frame mass
        centres in the frame-fixed axes; ic.., ie.. are the frame inertias rotated
        into the steer-axis-aligned frames; id.., if.. the wheel inertias.

        Returns
        -------
        dict of str to float
            Keys ``rf, rr, d1, d2, d3, l1, l2, l3, l4`` [m]; ``mc, md, me, mf`` (rear
            body, rear wheel, front frame, front wheel masses) [kg]; ``id11, id22,
            if11, if22, ic11, ic22, ic33, ic31, ie11, ie22, ie33, ie31`` [kg m^2];
            ``g`` [m/s^2].
        """
        lam = self.lam
        cl, sl = math.cos(lam), math.sin(lam)
        d1 = cl * (self.c + self.w - self.rR * math.tan(lam))
        d3 = -cl * (self.c - self.rF * math.tan(lam))
        d2 = (self.rR + d1 * sl - self.rF + d3 * sl) / cl
        l1 = self.xB * cl - self.zB * sl - self.rR * sl
        l2 = self.xB * sl + self.zB * cl + self.rR * cl
        l4 = (self.zH + self.rF) * cl + (self.xH - self.w) * sl
        l3 = (self.xH - self.w - l4 * sl) / cl
        rot = self.moore_rotation()
        ic = rot @ self.inertia_B() @ rot.T
        ie = rot @ self.inertia_H() @ rot.T
        return {
            "rf": self.rF, "rr": self.rR,
            "d1": d1, "d2": d2, "d3": d3,
            "l1": l1, "l2": l2, "l3": l3, "l4": l4,
            "mc": self.mB, "md": self.mR, "me": self.mH, "mf": self.mF,
            "id11": self.IRxx, "id22": self.IRyy,
            "if11": self.IFxx, "if22": self.IFyy,
            "ic11": ic[0, 0], "ic22": ic[1, 1], "ic33": ic[2, 2], "ic31": ic[2, 0],
            "ie11": ie[0, 0], "ie22": ie[1, 1], "ie33": ie[2, 2], "ie31": ie[2, 0],
            "g": self.g,
        }  # fmt: skip

    def moore_rotation(self) -> np.ndarray:
        """Rotation from the benchmark axes to Moore's frame-fixed axes (rotated by lam).

        Returns
        -------
        (3, 3) ndarray
            R with v_moore = R v_benchmark: ``[[cos lam, 0, -sin lam], [0, 1, 0],
            [sin lam, 0, cos lam]]`` [-] (a frame inertia rotates as R I R^T).
        """
        cl, sl = math.cos(self.lam), math.sin(self.lam)
        return np.array([[cl, 0.0, -sl], [0.0, 1.0, 0.0], [sl, 0.0, cl]])

    def inertia_B(self) -> np.ndarray:
        """Rear body inertia tensor about its mass centre, benchmark axes.

        Returns
        -------
        (3, 3) ndarray
            ``[[IBxx, 0, IBxz], [0, IByy, 0], [IBxz, 0, IBzz]]`` [kg m^2].
        """
        return np.array(
            [[self.IBxx, 0.0, self.IBxz], [0.0, self.IByy, 0.0], [self.IBxz, 0.0, self.IBzz]]
        )

    def inertia_H(self) -> np.ndarray:
        """Front frame inertia tensor about its mass centre, benchmark axes.

        Returns
        -------
        (3, 3) ndarray
            ``[[IHxx, 0, IHxz], [0, IHyy, 0], [IHxz, 0, IHzz]]`` [kg m^2].
        """
        return np.array(
            [[self.IHxx, 0.0, self.IHxz], [0.0, self.IHyy, 0.0], [self.IHxz, 0.0, self.IHzz]]
        )


# -- validation --------------------------------------------------------------------------
def _show(value: Any) -> str:
    """A value for a message, at most 60 characters."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _fail(param: str, rule: str, value: Any) -> None:
    if isinstance(value, tuple):
        value = tuple(float(v) for v in value)
    elif isinstance(value, (int, float, np.floating)):
        value = float(value)
    raise InputError(f"invalid bicycle parameter {param}={value!r}: {rule}")


def _check_inertia(label: str, names: tuple[str, str, str, str], tensor: np.ndarray) -> None:
    """Positive definite, and principal moments obey the triangle inequality."""
    xx, yy, zz, xz = names
    diag = {xx: tensor[0, 0], yy: tensor[1, 1], zz: tensor[2, 2]}
    for key, value in diag.items():
        if value <= 0.0:
            _fail(key, f"{label} moments of inertia must be positive", value)
    principal = np.linalg.eigvalsh(tensor)
    if principal[0] <= 0.0:
        _fail(
            xz,
            f"{label} inertia tensor is not positive definite (principal moments "
            f"{principal.round(6).tolist()}); reduce |{xz}| below sqrt({xx}*{zz})",
            tensor[0, 2],
        )
    a, b, c = principal
    tol = 1e-12 * c
    if c > a + b + tol:
        _fail(
            f"{xx}/{yy}/{zz}/{xz}",
            f"{label} principal moments {principal.round(6).tolist()} break the triangle "
            "inequality (the largest must not exceed the sum of the other two)",
            (tensor[0, 0], tensor[1, 1], tensor[2, 2], tensor[0, 2]),
        )


def _validate(p: BicycleParameters) -> None:
    for key in ("w", "rR", "rF", "g"):
        if getattr(p, key) <= 0.0:
            _fail(key, f"{PARAMETER_DOC[key][1]} must be positive", getattr(p, key))
    for key in ("mR", "mB", "mH", "mF"):
        if getattr(p, key) <= 0.0:
            _fail(key, f"{PARAMETER_DOC[key][1]} must be positive", getattr(p, key))
    if not -math.pi / 2 < p.lam < math.pi / 2:
        _fail("lam", "steer axis tilt must lie strictly between -pi/2 and pi/2 rad", p.lam)
    if abs(p.c) >= p.w:
        _fail("c", "trail magnitude must be smaller than the wheelbase w", p.c)
    if p.zB >= 0.0:
        _fail("zB", "rear body mass centre must be above the ground (z is down: zB < 0)", p.zB)
    if p.zH >= 0.0:
        _fail("zH", "front frame mass centre must be above the ground (z is down: zH < 0)", p.zH)
    for key, (unit, meaning) in PARAMETER_DOC.items():
        limit = PLAUSIBLE_LIMIT.get(unit)
        if limit is not None and not abs(getattr(p, key)) < limit:
            _fail(
                key,
                f"{meaning} is implausible for a bicycle: need |{key}| < {limit:g} {unit} "
                "(SI units: m, kg, kg m^2)",
                getattr(p, key),
            )
    for wheel, (ixx, iyy) in {"rear": ("IRxx", "IRyy"), "front": ("IFxx", "IFyy")}.items():
        dia, spin = getattr(p, ixx), getattr(p, iyy)
        if dia <= 0.0:
            _fail(ixx, f"{wheel} wheel diametral inertia must be positive", dia)
        if spin <= 0.0:
            _fail(iyy, f"{wheel} wheel spin inertia must be positive", spin)
        if spin > 2.0 * dia * (1 + 1e-12):
            _fail(
                iyy,
                f"{wheel} wheel breaks the triangle inequality: spin inertia {iyy} must not "
                f"exceed twice the diametral inertia {ixx}={dia}",
                spin,
            )
    _check_inertia("rear body", ("IBxx", "IByy", "IBzz", "IBxz"), p.inertia_B())
    _check_inertia("front frame", ("IHxx", "IHyy", "IHzz", "IHxz"), p.inertia_H())


# -- constructors ------------------------------------------------------------------------
_REQUIRED = tuple(f.name for f in fields(BicycleParameters) if f.name != "name")


def from_mapping(values: Mapping[str, Any], name: str = "custom") -> BicycleParameters:
    """Build parameters from a ``{parameter: value}`` mapping.

    Parameters
    ----------
    values : mapping of str to float
        Every field of :class:`BicycleParameters` except ``name`` [SI units].  The
        keys ``IRzz``, ``IFzz`` (must equal IRxx, IFxx) and ``name`` (ignored) are
        also accepted.
    name : str, optional
        Label of the bicycle. Default "custom".

    Returns
    -------
    BicycleParameters

    Raises
    ------
    ValueError
        If a parameter is missing or unknown, if IRzz/IFzz differ from IRxx/IFxx, or
        if a value breaks a rule (see :class:`BicycleParameters`).
    """
    bad_keys = [k for k in values if not isinstance(k, str)]
    if bad_keys:
        raise InputError(f"bicycle {name!r}: parameter names must be text, got {bad_keys[:3]}")
    missing = [k for k in _REQUIRED if k not in values]
    if missing:
        raise InputError(
            f"bicycle {name!r} is missing parameters {missing}; every one of "
            f"{list(_REQUIRED)} is required (IRzz = IRxx and IFzz = IFxx are implied)"
        )
    unknown = [k for k in values if k not in _REQUIRED and k not in ("name", "IRzz", "IFzz")]
    if unknown:
        raise InputError(
            f"bicycle {name!r} has unknown parameters {unknown}; known names are {list(_REQUIRED)}"
        )
    for wheel in ("R", "F"):
        zz = values.get(f"I{wheel}zz")
        if zz is None:
            continue
        xx = values[f"I{wheel}xx"]
        for key, v in ((f"I{wheel}zz", zz), (f"I{wheel}xx", xx)):
            if isinstance(v, (bool, np.bool_)) or not isinstance(
                v, (int, float, np.integer, np.floating)
            ):
                raise InputError(
                    f"bicycle {name!r}: parameter {key!r} must be a real number [kg m^2], "
                    f"got {_show(v)}"
                )
        if not math.isclose(float(zz), float(xx)):
            raise InputError(
                f"I{wheel}zz={zz} differs from I{wheel}xx={values[f'I{wheel}xx']}: the "
                "Whipple model assumes axisymmetric wheels (Izz = Ixx)"
            )
    return BicycleParameters(**{k: values[k] for k in _REQUIRED}, name=name)


def benchmark() -> BicycleParameters:
    """The benchmark bicycle, exact values of Meijaard et al. (2007) Table 1.

    IByy and IHyy are the paper's 11 and 0.06 kg m^2; lam = pi/10 exactly.

    Returns
    -------
    BicycleParameters
        Named ``"benchmark"``.
    """
    return BicycleParameters(
        w=1.02, c=0.08, lam=math.pi / 10.0, g=9.81,
        rR=0.3, mR=2.0, IRxx=0.0603, IRyy=0.12,
        xB=0.3, zB=-0.9, mB=85.0, IBxx=9.2, IByy=11.0, IBzz=2.8, IBxz=2.4,
        xH=0.9, zH=-0.7, mH=4.0, IHxx=0.05892, IHyy=0.06, IHzz=0.00708, IHxz=-0.00756,
        rF=0.35, mF=3.0, IFxx=0.1405, IFyy=0.28,
        name="benchmark",
    )  # fmt: skip


def steer_by_wire() -> BicycleParameters:
    """The riderless TU Delft steer-by-wire bicycle of the measured data.

    Values from the data set's README (``tudelft-sbw``; Pasma 2024, Dialynas et al.
    2018).  They are partly estimated.  IByy and IHyy are not given; since they do
    not enter the linear model we assume each body is planar-like in the x-z plane,
    Iyy = Ixx + Izz (the largest value the triangle inequality allows).  The rear
    wheel's IRyy is given; IFyy likewise.  The README's IFxx = 0.0644 with
    IFyy = 0.1289 breaks the wheel triangle inequality IFyy <= 2 IFxx by 0.08 %;
    0.0644 is consistent with 0.06445 rounded to three figures, which we use
    (the thin-hoop limit IFyy = 2 IFxx).

    Returns
    -------
    BicycleParameters
        Named ``"steer-by-wire"``.
    """
    IBxx, IBzz = 1.64, 1.94
    IHxx, IHzz = 0.0098, 0.00396
    return BicycleParameters(
        w=1.036, c=0.0803, lam=math.radians(18.2), g=9.81,
        rR=0.3498, mR=10.12, IRxx=0.1040, IRyy=0.1641,
        xB=0.462, zB=-0.698, mB=20.9, IBxx=IBxx, IByy=IBxx + IBzz, IBzz=IBzz, IBxz=0.654,
        xH=0.944, zH=-0.595, mH=0.6, IHxx=IHxx, IHyy=IHxx + IHzz, IHzz=IHzz, IHxz=-0.00044,
        rF=0.3498, mF=1.78, IFxx=0.06445, IFyy=0.1289,
        name="steer-by-wire",
    )  # fmt: skip


def _bicycleparameters_dir() -> Path:
    import bicycleparameters

    return Path(bicycleparameters.__file__).parent / "app-data" / "bicycles"


def _shipped_names() -> list[str]:
    try:
        root = _bicycleparameters_dir()
    except ImportError:  # pragma: no cover - dependency is required
        return []
    return sorted(
        p.name for p in root.iterdir() if (p / "Parameters" / f"{p.name}Benchmark.txt").exists()
    )


def from_bicycleparameters(name: str) -> BicycleParameters:
    """A bicycle shipped with ``bicycleparameters`` (Browser, Rigid, Pista, ...).

    Reads the package's ``<Name>Benchmark.txt`` and keeps the nominal values
    (uncertainties dropped).  Note: the shipped ``Benchmark`` file rounds IHxx,
    IHzz and IHxz; use :func:`benchmark` for the exact benchmark.  A measured IByy or
    IHyy outside the triangle-inequality range is clipped onto it with a
    ``UserWarning`` (Browser, Yellow, Yellowrev).

    Parameters
    ----------
    name : str
        Bicycle name, case-insensitive (one of the shipped folders with a
        ``Parameters/<Name>Benchmark.txt`` file).

    Returns
    -------
    BicycleParameters
        Named with the shipped spelling (e.g. ``"Browser"``).

    Raises
    ------
    ValueError
        If no shipped bicycle has this name, or its values break a rule.
    """
    from bicycleparameters.io import load_parameter_text_file

    names = _shipped_names()
    match = [n for n in names if n.lower() == name.lower()]
    if not match:
        raise InputError(
            f"unknown bicycleparameters bicycle {name!r}; shipped bicycles are {names}"
        )
    path = _bicycleparameters_dir() / match[0] / "Parameters" / f"{match[0]}Benchmark.txt"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # uncertainties: zero std devs
        raw = load_parameter_text_file(str(path))
    # some files (Rigid) also carry sub-body values (mG, mS, ...): keep the benchmark set
    values = {
        k: float(getattr(v, "nominal_value", v))
        for k, v in raw.items()
        if k in _REQUIRED or k in ("IRzz", "IFzz")
    }
    for body in ("B", "H"):
        _clip_iyy(values, body, match[0])
    return from_mapping(values, name=match[0])


def _clip_iyy(values: dict[str, float], body: str, bicycle: str) -> None:
    """Move a measured Iyy that breaks the triangle inequality onto its bound.

    Three shipped bicycles (Browser rear body, Yellow and Yellowrev front frames)
    have a pendulum-measured Iyy 1.6-2.3 % outside the physically possible range
    [p2 - p1, p1 + p2] set by the x-z principal moments p1 <= p2.  Iyy does not
    enter the linear model; in the nonlinear model it multiplies the (small)
    pitch rate.  We clip it and warn, rather than refuse the bicycle.
    """
    xx, yy, zz, xz = (values[f"I{body}{k}"] for k in ("xx", "yy", "zz", "xz"))
    p1, p2 = np.linalg.eigvalsh(np.array([[xx, xz], [xz, zz]]))
    lo, hi = p2 - p1, p1 + p2
    if not lo <= yy <= hi:
        new = min(max(yy, lo), hi)
        part = {"B": "rear body", "H": "front frame"}.get(body, body)
        warnings.warn(
            ParameterAdjusted(
                f"bicycle {bicycle!r}: its measured {part} I{body}yy = {yy:.5g} kg m^2 lies "
                f"outside the physically possible [{lo:.5g}, {hi:.5g}] (triangle inequality), "
                f"so bikeid uses I{body}yy = {new:.5g} ({100 * (new - yy) / yy:+.1f} %); "
                f"I{body}yy is not in the linear model (eigenvalues and critical speeds "
                "unchanged), only in the nonlinear model's pitch-rate terms"
            ),
            stacklevel=3,
        )
        values[f"I{body}yy"] = float(new)


class ParameterAdjusted(UserWarning):
    """A shipped bicycle's value was moved to make it physical; the message says which, by
    how much, and what it changes (commands print it as a note)."""


def from_file(path: str | Path) -> BicycleParameters:
    """Read bicycle parameters from a YAML (``.yml``/``.yaml``) or JSON file.

    Parameters
    ----------
    path : str or pathlib.Path
        File holding a mapping ``{parameter: value}`` in Meijaard notation; values
        SI (m, kg, kg m^2, rad, m/s^2).  An optional ``name`` key names the bicycle
        (default: the file's stem).  ``IRzz``/``IFzz`` may be given if equal to
        ``IRxx``/``IFxx``.

    Returns
    -------
    BicycleParameters

    Raises
    ------
    bikeid.sim.errors.InputError
        A ValueError: if the file does not exist, has another extension, is over
        :data:`MAX_FILE_BYTES`, does not parse (:func:`bikeid.sim.textformats.loads_json`,
        :func:`~bikeid.sim.textformats.loads_yaml`: duplicate keys, NaN, deep nesting are
        refused), does not hold a mapping, or its parameters are missing, unknown or invalid
        (:func:`from_mapping`); the message names the file and the parameter.
    """
    path = Path(path)
    where = f"parameter file {str(path)!r}"
    if not path.exists():
        raise InputError(f"{where} does not exist")
    suffix = path.suffix.lower()
    if suffix not in (".yml", ".yaml", ".json"):
        raise InputError(f"{where}: unknown extension {path.suffix!r}; use .yaml, .yml or .json")
    if not path.is_file():
        raise InputError(f"{where} is not a file")
    if path.stat().st_size > MAX_FILE_BYTES:
        raise InputError(
            f"{where} is {path.stat().st_size:,} bytes, more than a parameter file's "
            f"{MAX_FILE_BYTES:,}; is it the right file?"
        )
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(
            f"{where} is not UTF-8 text (byte {exc.start}); save it as UTF-8"
        ) from None
    values = loads_json(text, where) if suffix == ".json" else loads_yaml(text, where)
    if not isinstance(values, Mapping):
        raise InputError(f"{where} must hold a mapping of name: value, got {type(values).__name__}")
    name = values.get("name", path.stem)
    if not isinstance(name, str):
        raise InputError(f"{where}: 'name' must be text, got {_show(name)}")
    try:
        return from_mapping(values, name=name)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


#: Largest parameter file read [bytes] (a parameter file is about 1 kB).
MAX_FILE_BYTES = 1_000_000


_ALIASES = {
    "benchmark": benchmark,
    "meijaard2007": benchmark,
    "steer-by-wire": steer_by_wire,
    "sbw": steer_by_wire,
    "tudelft-sbw": steer_by_wire,
}


def known_names() -> list[str]:
    """Names accepted by :func:`by_name` (besides file paths).

    Returns
    -------
    list of str
        The aliases (``benchmark``, ``meijaard2007``, ``steer-by-wire``, ``sbw``,
        ``tudelft-sbw``), then the bicycles shipped with ``bicycleparameters`` except
        its ``Benchmark``.
    """
    shipped = [n for n in _shipped_names() if n.lower() != "benchmark"]
    return list(_ALIASES) + shipped


def by_name(name: str) -> BicycleParameters:
    """Resolve a bicycle by name or file path.

    ``benchmark`` is the exact Meijaard (2007) bicycle; ``steer-by-wire`` (or
    ``sbw``) the TU Delft bicycle; any name shipped by ``bicycleparameters``
    (case-insensitive); or a path to a ``.yaml``/``.json`` file.

    Parameters
    ----------
    name : str
        An alias (case-insensitive, surrounding blanks ignored: ``benchmark``,
        ``meijaard2007``, ``steer-by-wire``, ``sbw``, ``tudelft-sbw``), a
        ``bicycleparameters`` bicycle, or a path ending in ``.yaml``, ``.yml`` or
        ``.json``.

    Returns
    -------
    BicycleParameters

    Raises
    ------
    ValueError
        If the name is unknown, or the file or bicycle is invalid.
    """
    key = name.strip().lower()
    if key in _ALIASES:
        return _ALIASES[key]()
    if key.endswith((".yaml", ".yml", ".json")):
        return from_file(name)
    if any(n.lower() == key for n in _shipped_names()):
        return from_bicycleparameters(name)
    raise InputError(
        f"unknown bicycle {name!r}; choose one of {known_names()} or give a .yaml/.json file"
    )
