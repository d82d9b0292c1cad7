"""Speed-adaptive Mamdani fuzzy roll-angle controller (a reconstruction of Chen & Dao).

Chen & Dao's membership functions, rule table and scaling factors are not public
(controllers.md §1); every choice below is ours and is listed in docs/controllers.md.

Inference (normalized, everything on [-1, 1]):

- inputs E = clip(G_E e) and CE = clip(G_CE e'), e = phi_ref - phi [rad],
  e' = phi_ref' - phidot [rad/s] (the reference's exact rate, the measured roll rate);
- 7 triangular MFs per variable (NB, NM, NS, ZE, PS, PM, PB), centres c_k = -1 + k/3,
  half-width 1/3 (the end MFs are half triangles on the universe);
- diagonal fuzzy-PD rule table: (E_i, CE_j) -> U_clip(i+j-3, 0, 6);
- AND = min, implication = min (clipping), aggregation = max, centroid defuzzification
  (scikit-fuzzy's Mamdani semantics);
- output T = G_U(v) U [N m].

Speed adaptation: G_U(v) = G_U0 s(v), s(v) = min(1, sqrt(v_a / v)) on the measured (or
design) speed: full torque scale at and below v_a, less above, where the plant's
steer-to-roll gain is larger.  G_U0 < 0 (benchmark sign convention: torque into the
lean).  Near the origin the surface slope is 3/2 (U ~ 1.5 (E + CE) for small inputs), so
the linear equivalent is Kp ~ 1.5 G_U G_E, Kd ~ 1.5 G_U G_CE; the defaults give
(Kp, Kd) ~ (-200, -80) s(v), a PD pair that keeps the linear benchmark stable at
1-15 m/s for loop-gain factors 0.67-3 (the surface slope varies between 1 and 1.5).

Evaluation paths:

- :func:`mamdani` — exact vectorized numpy Mamdani: the aggregated output set is
  piecewise linear, all its kinks are enumerated (MF vertices, cut-level crossings,
  crossings between neighbouring clipped sets), so the centroid is exact to round-off;
- :class:`ControlSurface` — the normalized surface tabulated on an n x n grid
  (default n = 301, so every MF vertex -1, -2/3, ..., 1 is a node) and looked up by
  scalar bilinear interpolation in pure Python (the in-loop path, a few microseconds);
- :func:`skfuzzy_simulation` — scikit-fuzzy's ``ControlSystemSimulation`` on the same
  design, with the rule firing order cached (reference only: milliseconds per call).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from .base import DEFAULT_SAMPLE_TIME, I_PHI, I_PHIDOT, Controller

__all__ = [
    "ControlSurface",
    "FuzzyController",
    "MF_CENTRES",
    "control_surface",
    "mamdani",
    "rule_table",
    "skfuzzy_simulation",
]

N_MF = 7
H = 1.0 / 3.0  # MF half-width
MF_CENTRES = tuple(-1.0 + k * H for k in range(N_MF))
TERMS = ("NB", "NM", "NS", "ZE", "PS", "PM", "PB")


def rule_table() -> list[list[int]]:
    """Output MF index for (E index i, CE index j): the diagonal table clip(i + j - 3, 0, 6).

    Returns
    -------
    list of list of int, shape (7, 7)
        ``table[i][j]`` is the index into :data:`MF_CENTRES` (terms NB, NM, NS, ZE, PS,
        PM, PB) of the output MF fired by E term i and CE term j.
    """
    return [[min(max(i + j - 3, 0), N_MF - 1) for j in range(N_MF)] for i in range(N_MF)]


def _memberships(x: np.ndarray) -> np.ndarray:
    """(N, 7) triangle memberships of x (already clipped to [-1, 1])."""
    c = np.asarray(MF_CENTRES)
    return np.clip(1.0 - np.abs(x[:, None] - c[None, :]) / H, 0.0, 1.0)


def mamdani(e_n, ce_n, chunk: int = 8192) -> np.ndarray:
    """Exact Mamdani output U in [-8/9, 8/9] for normalized inputs (clipped to [-1, 1]).

    Min AND, min implication, max aggregation and centroid defuzzification over the
    universe [-1, 1]; the centroid of the piecewise-linear aggregated set is computed
    exactly (module docstring).

    Parameters
    ----------
    e_n : array_like
        Normalized roll error E = G_E (phi_ref - phi) [-]; clipped to [-1, 1].
    ce_n : array_like
        Normalized error rate CE = G_CE (phi_ref' - phidot) [-], broadcastable with
        ``e_n``; clipped to [-1, 1].
    chunk : int, optional
        Number of points evaluated per vectorized block (memory bound only; default 8192).

    Returns
    -------
    ndarray
        Normalized output U [-], the broadcast shape of ``e_n`` and ``ce_n``; the torque
        is G_U(v) U [N m].
    """
    e_n = np.clip(np.asarray(e_n, dtype=float), -1.0, 1.0)
    ce_n = np.clip(np.asarray(ce_n, dtype=float), -1.0, 1.0)
    shape = np.broadcast_shapes(e_n.shape, ce_n.shape)
    e_flat = np.broadcast_to(e_n, shape).ravel()
    ce_flat = np.broadcast_to(ce_n, shape).ravel()
    out = np.empty(e_flat.size)
    for a in range(0, e_flat.size, chunk):
        out[a : a + chunk] = _mamdani_flat(e_flat[a : a + chunk], ce_flat[a : a + chunk])
    return out.reshape(shape)


def _mamdani_flat(e: np.ndarray, ce: np.ndarray) -> np.ndarray:
    n = e.size
    mu_e, mu_c = _memberships(e), _memberships(ce)
    w = np.zeros((n, N_MF))  # firing level of each output MF (max over its rules)
    table = rule_table()
    for i in range(N_MF):
        for j in range(N_MF):
            k = table[i][j]
            np.maximum(w[:, k], np.minimum(mu_e[:, i], mu_c[:, j]), out=w[:, k])
    c = np.asarray(MF_CENTRES)
    # candidate kinks of the aggregated set: vertices and midpoints (static), and for
    # every output MF k the points where MF k or a neighbour k +- 1 reaches level w_k
    static = np.concatenate([c, 0.5 * (c[1:] + c[:-1])])
    off = H * (1.0 - w)  # (n, 7) distance from a centre where a MF equals w_k
    dyn = []
    for k in range(N_MF):
        for j in (k - 1, k, k + 1):
            if 0 <= j < N_MF:
                dyn.append(c[j] - off[:, k])
                dyn.append(c[j] + off[:, k])
    pts = np.concatenate([np.broadcast_to(static, (n, static.size)), np.stack(dyn, 1)], axis=1)
    pts = np.sort(np.clip(pts, -1.0, 1.0), axis=1)
    mf = np.clip(1.0 - np.abs(pts[:, :, None] - c[None, None, :]) / H, 0.0, 1.0)
    agg = np.minimum(mf, w[:, None, :]).max(axis=2)  # (n, m)
    x1, x2 = pts[:, :-1], pts[:, 1:]
    y1, y2 = agg[:, :-1], agg[:, 1:]
    dx = x2 - x1
    area = (0.5 * dx * (y1 + y2)).sum(axis=1)
    moment = (dx * (x1 * (2 * y1 + y2) + x2 * (y1 + 2 * y2)) / 6.0).sum(axis=1)
    return moment / area


class ControlSurface:
    """Normalized surface U(E, CE) on an n x n grid over [-1, 1]^2 with scalar bilinear
    lookup (inputs outside [-1, 1] are clipped, like scikit-fuzzy's ``clip_to_bounds``).

    ``n - 1`` must be a multiple of 6 so that every MF vertex is a grid node.

    ``surface(e, ce)`` with normalized inputs E, CE [-] returns the interpolated
    normalized output U [-].

    Parameters
    ----------
    n : int, optional
        Grid size per axis (default 301), n >= 7 and (n - 1) % 6 == 0.

    Attributes
    ----------
    n : int
        Grid size per axis.
    values : (n, n) ndarray
        Exact :func:`mamdani` values at the nodes, rows indexed by E and columns by CE
        (read-only).

    Raises
    ------
    ValueError
        If ``n`` violates the conditions above.
    """

    def __init__(self, n: int = 301):
        n = int(n)
        if n < 7 or (n - 1) % 6:
            raise ValueError(f"surface size n must satisfy (n - 1) % 6 == 0 and n >= 7, got {n}")
        self.n = n
        self.values = control_surface(n)
        self._rows = self.values.tolist()  # rows indexed by E, columns by CE
        self._scale = (n - 1) / 2.0

    def __call__(self, e: float, ce: float) -> float:
        s = self._scale
        x = (e + 1.0) * s
        y = (ce + 1.0) * s
        top = self.n - 1
        if x <= 0.0:
            x = 0.0
        elif x >= top:
            x = top - 1e-9
        if y <= 0.0:
            y = 0.0
        elif y >= top:
            y = top - 1e-9
        i = int(x)
        j = int(y)
        fx = x - i
        fy = y - j
        r0 = self._rows[i]
        r1 = self._rows[i + 1]
        a = r0[j] + fy * (r0[j + 1] - r0[j])
        b = r1[j] + fy * (r1[j + 1] - r1[j])
        return a + fx * (b - a)


@functools.lru_cache(maxsize=4)
def control_surface(n: int = 301) -> np.ndarray:
    """(n, n) exact surface values at the grid nodes; cached per process (read-only).

    Parameters
    ----------
    n : int, optional
        Number of nodes per axis on [-1, 1] (default 301).

    Returns
    -------
    (n, n) ndarray
        U(E_i, CE_j) [-] with E_i = CE_i = ``linspace(-1, 1, n)[i]``; read-only.
    """
    g = np.linspace(-1.0, 1.0, n)
    E, CE = np.meshgrid(g, g, indexing="ij")
    vals = mamdani(E, CE)
    vals.setflags(write=False)
    return vals


def skfuzzy_simulation(n_universe: int = 301):
    """A scikit-fuzzy ``ControlSystemSimulation`` of the same design (inputs "E", "CE",
    output "U"), with the rule order cached so that a ``compute()`` costs ms, not tens
    of ms.  For reference checks only; never call it in a simulation loop.

    Parameters
    ----------
    n_universe : int, optional
        Points of the discretized universe [-1, 1] (default 301); ``n_universe - 1``
        must be a multiple of 6.

    Returns
    -------
    skfuzzy.control.ControlSystemSimulation
        Set ``sim.input["E"]``, ``sim.input["CE"]`` (normalized [-]), call
        ``sim.compute()`` and read ``sim.output["U"]`` [-]; inputs are clipped to the
        universe.

    Raises
    ------
    ValueError
        If ``n_universe - 1`` is not a multiple of 6.
    """
    import skfuzzy as fuzz
    from skfuzzy import control as ctrl
    from skfuzzy.control.controlsystem import RuleOrderGenerator

    class _CachedRulesSystem(ctrl.ControlSystem):
        # ControlSystem.rules builds a new generator (empty cache) on every access
        @property
        def rules(self):
            gen = self.__dict__.get("_rule_gen")
            if gen is None:
                gen = self.__dict__["_rule_gen"] = RuleOrderGenerator(self)
            return gen

    if (n_universe - 1) % 6:
        raise ValueError("n_universe - 1 must be a multiple of 6 (MF vertices on the grid)")
    u = np.linspace(-1.0, 1.0, n_universe)
    E = ctrl.Antecedent(u, "E")
    CE = ctrl.Antecedent(u, "CE")
    U = ctrl.Consequent(u, "U", defuzzify_method="centroid")
    for var in (E, CE, U):
        for name, c in zip(TERMS, MF_CENTRES, strict=True):
            var[name] = fuzz.trimf(u, [c - H, c, c + H])
    table = rule_table()
    rules = [
        ctrl.Rule(E[TERMS[i]] & CE[TERMS[j]], U[TERMS[table[i][j]]])
        for i in range(N_MF)
        for j in range(N_MF)
    ]
    return ctrl.ControlSystemSimulation(_CachedRulesSystem(rules), clip_to_bounds=True)


#: Defaults: roll-error scale 0.25 rad, error-rate scale 0.625 rad/s, torque scale
#: -33.3 N m: Kp ~ 1.5 * -33.3 / 0.25 = -200 N m/rad, Kd ~ 1.5 * -33.3 / 0.625 = -80 N m s/rad.
DEFAULT_E_MAX = 0.25
DEFAULT_CE_MAX = 0.625
DEFAULT_TORQUE_SCALE = -200.0 * DEFAULT_E_MAX / 1.5
DEFAULT_ADAPT_SPEED = 3.0


class FuzzyController(Controller):
    """Fuzzy-PD roll tracker; see the module docstring.

    Parameters: ``e_max`` [rad] and ``ce_max`` [rad/s] are the input ranges
    (G_E = 1 / e_max, G_CE = 1 / ce_max); ``torque_scale`` G_U0 [N m] (negative);
    ``adapt_speed`` v_a [m/s] of s(v) (``None`` disables adaptation, s = 1);
    ``surface_size`` the table size n; ``exact=True`` evaluates :func:`mamdani` per call
    instead of the table (about 100x slower).

    Parameters
    ----------
    e_max : float, optional
        Roll-error range [rad] (default 0.25), positive; G_E = 1 / e_max.
    ce_max : float, optional
        Error-rate range [rad/s] (default 0.625), positive; G_CE = 1 / ce_max.
    torque_scale : float, optional
        G_U0 [N m] (default -200 * 0.25 / 1.5 = -33.3), finite and non-zero; negative
        steers into the lean (benchmark signs).
    adapt_speed : float or None, optional
        v_a [m/s] of s(v) = min(1, sqrt(v_a / v)) (default 3.0); None for s = 1.
    surface_size : int, optional
        Table size n of :class:`ControlSurface` (default 301).
    exact : bool, optional
        Evaluate :func:`mamdani` at every call instead of the table (default False).
    sample_time, saturation, reference, design_speed
        As in :class:`~controllers.base.Controller` ([s], [N m], [rad] of t [s], [m/s]).

    Attributes
    ----------
    e_max, ce_max : float
        Input ranges [rad, rad/s].
    torque_scale : float
        G_U0 [N m].
    adapt_speed : float or None
        v_a [m/s].
    exact : bool
        Whether the exact inference is used.
    surface : ControlSurface
        The tabulated surface.

    Raises
    ------
    ValueError
        If ``e_max`` or ``ce_max`` is not positive and finite, ``torque_scale`` is zero
        or not finite, ``adapt_speed`` is not positive (and not None), or
        ``surface_size`` is invalid.
    """

    name = "fuzzy"

    def __init__(
        self,
        e_max: float = DEFAULT_E_MAX,
        ce_max: float = DEFAULT_CE_MAX,
        torque_scale: float = DEFAULT_TORQUE_SCALE,
        adapt_speed: float | None = DEFAULT_ADAPT_SPEED,
        *,
        surface_size: int = 301,
        exact: bool = False,
        sample_time: float = DEFAULT_SAMPLE_TIME,
        saturation: float = math.inf,
        reference: Callable[[float], float] | None = None,
        design_speed: float | None = None,
    ):
        for label, val in (("e_max", e_max), ("ce_max", ce_max)):
            if not (math.isfinite(val) and val > 0):
                raise ValueError(f"{label} must be positive and finite, got {val}")
        if not math.isfinite(torque_scale) or torque_scale == 0:
            raise ValueError(f"torque_scale must be finite and non-zero, got {torque_scale}")
        if adapt_speed is not None and not (math.isfinite(adapt_speed) and adapt_speed > 0):
            raise ValueError(f"adapt_speed must be positive (or None), got {adapt_speed}")
        self.e_max, self.ce_max = float(e_max), float(ce_max)
        self.torque_scale = float(torque_scale)
        self.adapt_speed = None if adapt_speed is None else float(adapt_speed)
        self.exact = bool(exact)
        self.surface = ControlSurface(surface_size)
        super().__init__(sample_time, saturation, reference, design_speed)

    def scale(self, v: float) -> float:
        """s(v) = min(1, sqrt(v_a / v)); 1 without adaptation or at v <= 0.

        Parameters
        ----------
        v : float
            Scheduling speed [m/s].

        Returns
        -------
        float
            Torque-scale factor s(v) in (0, 1] [-].
        """
        va = self.adapt_speed
        if va is None or v <= va:
            return 1.0
        return math.sqrt(va / v)

    def _control(self, t: float, y: Sequence[float], dt: float) -> float:
        r, rd = self._reference_and_rate(t, dt)
        e = (r - y[I_PHI]) / self.e_max
        ce = (rd - y[I_PHIDOT]) / self.ce_max
        if self.exact:
            u = float(mamdani(e, ce))
        else:
            u = self.surface(e, ce)
        return self.torque_scale * self.scale(self.speed(y)) * u

    def _gains_description(self) -> dict[str, Any]:
        return {
            "law": "T = G_U0 s(v) U(e / e_max, edot / ce_max), s = min(1, sqrt(v_a / v))",
            "e_max": self.e_max, "ce_max": self.ce_max, "torque_scale": self.torque_scale,
            "adapt_speed": self.adapt_speed, "mfs": "7 triangles, centres -1:1/3:1",
            "rules": "diagonal clip(i + j - 3)", "inference": "min/min/max/centroid",
            "evaluation": "exact" if self.exact else f"bilinear table {self.surface.n}^2",
        }  # fmt: skip
