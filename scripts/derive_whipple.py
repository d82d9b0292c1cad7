"""Derive the nonlinear Carvallo-Whipple bicycle and emit numba-compilable code.

Run ``python scripts/derive_whipple.py`` (about a minute) to regenerate
``sim/_whipple_generated.py``; ``--check`` compares a fresh derivation with the
committed file numerically instead of writing it.

Model (Moore 2012 coordinates, sympy.physics.mechanics ``KanesMethod``): four rigid
bodies, rear frame C (with rider), rear wheel D, front frame E, front wheel F;
knife-edge wheels rolling without slip on flat ground.  Frames: N inertial
(x forward, y right, z down), A yaw (q3 about N3), B roll (q4 about A1),
C rear frame pitch (q5 about B2; q5 = lam when upright), D rear wheel (q6 about
C2), E front frame steer (q7 about C3, the steer axis), F front wheel (q8 about E2).
q1, q2 are the rear contact point's N1, N2 coordinates (ignorable; integrated
from :func:`contact_rates`).  Speeds u_i = q_i'.  The holonomic constraint (front
contact on the ground) makes pitch q5 dependent; the nonholonomic constraints
(front contact point of the wheel at rest) leave u4, u6, u7 independent and
u3, u5, u8 dependent.  Kane's equations use ``constraint_solver="CRAMER"``.

Loads: gravity (along A3), steer torque T_delta (C on E about C3, reaction on C),
roll torque T_phi (on C about A1), lateral force F (along A2, at a rear-frame
point lf1*C1 + lf3*C3 from the rear wheel centre), rear drive torque T_R (C on D
about C2, reaction on C).  The runtime adds an extra generalized-force 3-vector
to the dynamic rows of (u4, u6, u7).

Emitted functions (parameter vector ``p`` in :data:`PARAMETERS` order, inputs
``r = [T_delta, T_phi, F, T_R]``, speeds ``u = [u4, u6, u7, u3, u5, u8]``):

- ``holonomic(q4, q5, q7, p) -> (residual, d residual / d q5)`` [m, m/rad]
- ``velocity_constraint(q4, q5, q7, p, Ad, Ai)``: fills 3x3 arrays so that
  ``Ad @ [u3, u5, u8] + Ai @ [u4, u6, u7] = 0``
- ``mass_forcing(q4, q5, q7, u, p, r, M, f)``: 6x6 ``M`` and 6-vector ``f`` with
  ``M @ u' = f`` (rows 0-2 Kane's dynamic equations of u4, u6, u7; rows 3-5 the
  time derivative of the velocity constraints)
- ``input_matrix(q4, q5, q7, p, G)``: 6x4 ``G = d f / d r``
- ``energy(q4, q5, q7, u, p) -> (kinetic, potential)`` [J]; potential zero with
  all mass centres at ground level
- ``contact(q3, q4, q5, q7, u, p, out)``: ``out = [q1', q2', xF - q1, yF - q2]``,
  the rear contact rates and the front contact position relative to the rear
  contact, in N.
- ``contact_forces(q4, q5, q7, u, ud, p, r) -> (N_R, N_F)`` [N]: normal contact
  forces of the ground on the rear and front wheel along -A3 (up; positive = the
  ground pushes up), with ``ud = u'`` in the order of ``u`` (from ``mass_forcing``).
  Newton-Euler for the whole bicycle (:func:`_newton_euler`): the moment of momentum
  about the rear contact along the horizontal normal to the contact line gives N_F,
  vertical momentum gives N_R.  Only T_phi and F of ``r`` enter directly (T_delta
  and T_R act between bodies).
- ``momentum(q3, q4, q5, q7, u, p, out)``: ``out`` (12,) = linear momentum
  [kg m/s], moment of momentum about the rear contact point [kg m^2/s], first
  moment of mass about the rear contact [kg m] and the lateral-force point relative
  to the rear contact [m], each in N components (for the independent test of the
  contact forces by differentiating momenta numerically).

The Whipple model holds both wheels on the ground (bilateral contact); a run is only
physical while N_R > 0 and N_F > 0 (``sim.integrate`` stops at ``wheel_unloaded``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import sympy as sm
import sympy.physics.mechanics as me
from sympy.printing.pycode import PythonCodePrinter

from bikeid.dataset.files import atomic_write_text, check_output_path

ROOT = Path(__file__).resolve().parents[1]
TARGET = ROOT / "sim" / "_whipple_generated.py"

#: Order of the numerical parameter vector (Moore 2012 names + lateral-force point).
PARAMETERS = (
    "rf", "rr", "d1", "d2", "d3", "l1", "l2", "l3", "l4",
    "mc", "md", "me", "mf", "id11", "id22", "if11", "if22",
    "ic11", "ic22", "ic33", "ic31", "ie11", "ie22", "ie33", "ie31", "g", "lf1", "lf3",
)  # fmt: skip
INPUTS = ("T_delta", "T_phi", "F", "T_R")


def derive() -> dict:
    """Kane's equations of the Whipple bicycle; returns the symbolic pieces."""
    t = me.dynamicsymbols._t
    q3, q4, q5, q6, q7, q8 = me.dynamicsymbols("q3:9")
    u3, u4, u5, u6, u7, u8 = me.dynamicsymbols("u3:9")
    par = sm.symbols(PARAMETERS, real=True)
    P = dict(zip(PARAMETERS, par, strict=True))
    T_delta, T_phi, F_lat, T_R = sm.symbols(INPUTS, real=True)

    N = me.ReferenceFrame("N")
    A = N.orientnew("A", "Axis", (q3, N.z))
    B = A.orientnew("B", "Axis", (q4, A.x))
    C = B.orientnew("C", "Axis", (q5, B.y))
    D = C.orientnew("D", "Axis", (q6, C.y))
    E = C.orientnew("E", "Axis", (q7, C.z))
    Fw = E.orientnew("F", "Axis", (q8, E.y))
    A.set_ang_vel(N, u3 * N.z)
    B.set_ang_vel(A, u4 * A.x)
    C.set_ang_vel(B, u5 * B.y)
    D.set_ang_vel(C, u6 * C.y)
    E.set_ang_vel(C, u7 * C.z)
    Fw.set_ang_vel(E, u8 * E.y)

    dn = me.Point("dn")  # rear wheel material point at the contact: at rest
    dn.set_vel(N, 0)
    do = dn.locatenew("do", -P["rr"] * B.z)
    co = do.locatenew("co", P["l1"] * C.x + P["l2"] * C.z)
    ce = do.locatenew("ce", P["d1"] * C.x)
    fo = ce.locatenew("fo", P["d2"] * E.z + P["d3"] * E.x)
    eo = fo.locatenew("eo", P["l3"] * E.x + P["l4"] * E.z)
    down = me.cross(E.y, me.cross(A.z, E.y))  # in the front wheel plane, towards ground
    down_len = sm.sqrt(down.dot(down))
    fn = fo.locatenew("fn", P["rf"] * down / down_len)
    pF = do.locatenew("pF", P["lf1"] * C.x + P["lf3"] * C.z)  # lateral force point

    do.v2pt_theory(dn, N, D)
    co.v2pt_theory(do, N, C)
    ce.v2pt_theory(do, N, C)
    pF.v2pt_theory(do, N, C)
    fo.v2pt_theory(ce, N, E)
    eo.v2pt_theory(fo, N, E)
    fn.v2pt_theory(fo, N, Fw)

    holonomic = fn.pos_from(dn).dot(A.z)
    vfn = fn.vel(N)
    nonholonomic = [vfn.dot(A.x), vfn.dot(A.y), vfn.dot(A.z)]

    Ic = me.inertia(C, P["ic11"], P["ic22"], P["ic33"], 0, 0, P["ic31"])
    Id = me.inertia(C, P["id11"], P["id22"], P["id11"])
    Ie = me.inertia(E, P["ie11"], P["ie22"], P["ie33"], 0, 0, P["ie31"])
    If = me.inertia(E, P["if11"], P["if22"], P["if11"])
    bodies = [
        me.RigidBody("C", co, C, P["mc"], (Ic, co)),
        me.RigidBody("D", do, D, P["md"], (Id, do)),
        me.RigidBody("E", eo, E, P["me"], (Ie, eo)),
        me.RigidBody("F", fo, Fw, P["mf"], (If, fo)),
    ]
    g = P["g"]
    loads = [
        (co, P["mc"] * g * A.z),
        (do, P["md"] * g * A.z),
        (eo, P["me"] * g * A.z),
        (fo, P["mf"] * g * A.z),
        (E, T_delta * C.z),
        (C, -T_delta * C.z + T_phi * A.x - T_R * C.y),
        (D, T_R * C.y),
        (pF, F_lat * A.y),
    ]

    kd = [
        qi.diff(t) - ui
        for qi, ui in zip((q3, q4, q5, q6, q7, q8), (u3, u4, u5, u6, u7, u8), strict=True)
    ]
    kane = me.KanesMethod(
        N,
        q_ind=[q3, q4, q6, q7, q8],
        u_ind=[u4, u6, u7],
        kd_eqs=kd,
        q_dependent=[q5],
        configuration_constraints=[holonomic],
        u_dependent=[u3, u5, u8],
        velocity_constraints=nonholonomic,
        constraint_solver="CRAMER",
    )
    kane.kanes_equations(bodies, loads)
    M = kane.mass_matrix
    f = kane.forcing

    # energies: kinetic from body velocities, potential of gravity (z down)
    ke = sum(b.kinetic_energy(N) for b in bodies)
    pe = -g * sum(b.mass * b.masscenter.pos_from(dn).dot(A.z) for b in bodies)

    # rear contact rates in N (contact point moves along A1 at -rr (u5 + u6)),
    # and front contact relative to the rear contact, in N
    vdn = -P["rr"] * (u5 + u6)
    rates = sm.Matrix([vdn * sm.cos(q3), vdn * sm.sin(q3)])
    rel = fn.pos_from(dn)
    front = [rel.dot(N.x), rel.dot(N.y)]

    contact_forces, momentum = _newton_euler(kane, bodies, P, dn, fn, pF, A, N, C, F_lat, T_phi)

    return {
        "q": (q3, q4, q5, q7),
        "u": (u4, u6, u7, u3, u5, u8),
        "p": par,
        "r": (T_delta, T_phi, F_lat, T_R),
        "holonomic": holonomic,
        "nonholonomic": nonholonomic,
        "M": M,
        "f": f,
        "ke": ke,
        "pe": pe,
        "rates": rates,
        "front": front,
        "kane": kane,
        "ud": tuple(ui.diff(t) for ui in (u4, u6, u7, u3, u5, u8)),
        "contact_forces": contact_forces,
        "momentum": momentum,
    }


def _newton_euler(kane, bodies, P, dn, fn, pF, A, N, C, F_lat, T_phi):
    """Normal contact forces by Newton-Euler for the whole bicycle, and its momenta.

    Ground forces: at the rear contact dn (tangential Rx A1 + Ry A2, normal -N_R A3) and
    at the front contact fn (-N_F A3 normal); N_R, N_F > 0 when the ground pushes up.
    Other external loads: gravity, the lateral force F at pF and the roll torque T_phi
    A1 on C; T_delta, T_R and the steer/roll effects act between bodies (or, for roll
    effects, exactly as T_phi does) and enter only through the accelerations.

    - Moment of momentum about the fixed point coincident with dn, component along the
      horizontal e = A3 x r (r = fn - dn, horizontal by the holonomic constraint): the
      rear ground force has no moment, the front tangential force's moment is vertical,
      so only N_F remains: N_F = e . (dH/dt - M_known) / |r|^2, with dH/dt =
      sum (r_i - dn) x m_i a_i + I_i alpha_i + w_i x (I_i w_i).
    - Newton along A3: N_R = m g - N_F - sum m_i a_i . A3.

    Accelerations come from the velocities by time differentiation (q' replaced by u);
    they are linear in u' = [u4', u6', u7', u3', u5', u8'], evaluated with u' from
    ``mass_forcing``.  Also returned, for the independent check: linear momentum,
    moment of momentum about dn, first moment of mass about dn and the lateral-force
    point relative to dn, all in N components.
    """
    kdd = kane.kindiffdict()

    def ddt(vec):
        return vec.dt(N).subs(kdd)

    g = P["g"]
    mass = sum(b.mass for b in bodies)
    lin_rate = sum((b.mass * ddt(b.masscenter.vel(N)) for b in bodies), me.Vector(0))
    h_rate = me.Vector(0)
    known = me.Vector(0)
    lin = me.Vector(0)
    h_dn = me.Vector(0)
    first = me.Vector(0)
    for b in bodies:
        rel = b.masscenter.pos_from(dn)
        w = b.frame.ang_vel_in(N)
        alpha = ddt(w)
        inertia = b.inertia[0]
        h_rate += rel.cross(b.mass * ddt(b.masscenter.vel(N)))
        h_rate += inertia.dot(alpha) + w.cross(inertia.dot(w))
        known += rel.cross(b.mass * g * A.z)
        lin += b.mass * b.masscenter.vel(N)
        h_dn += rel.cross(b.mass * b.masscenter.vel(N)) + inertia.dot(w)
        first += b.mass * rel
    known += pF.pos_from(dn).cross(F_lat * A.y) + T_phi * A.x
    r = fn.pos_from(dn)
    rx, ry = r.dot(A.x), r.dot(A.y)
    # e = A3 x r = -ry A1 + rx A2; |r|^2 = rx^2 + ry^2
    diff = h_rate - known
    n_front = (-ry * diff.dot(A.x) + rx * diff.dot(A.y)) / (rx**2 + ry**2)
    n_rear = mass * g - n_front - lin_rate.dot(A.z)
    in_n = [
        vec.dot(axis) for vec in (lin, h_dn, first, pF.pos_from(dn)) for axis in (N.x, N.y, N.z)
    ]
    return [n_rear, n_front], in_n


def _plain(expr, q, u):
    """Replace dynamic symbols by plain symbols named after them."""
    t = me.dynamicsymbols._t
    subs = {}
    for s in list(q) + list(u):
        subs[s.diff(t)] = sm.Symbol(f"{s.func.__name__}d")
        subs[s] = sm.Symbol(s.func.__name__)
    return sm.sympify(expr).xreplace(subs)


class _Printer(PythonCodePrinter):
    def _print_Pow(self, expr, rational=False):
        base, exp = expr.as_base_exp()
        if exp.is_Integer and 1 < int(exp) <= 4:
            b = self.parenthesize(base, 100)
            return "*".join([b] * int(exp))
        if exp == -1:
            return f"1.0/{self.parenthesize(base, 100)}"
        if exp.is_Integer and -4 <= int(exp) < -1:
            b = self.parenthesize(base, 100)
            return "1.0/(" + "*".join([b] * -int(exp)) + ")"
        return super()._print_Pow(expr, rational=rational)


_PRINTER = _Printer({"standard": "python3"})


def _code(expr) -> str:
    return _PRINTER.doprint(expr)


def _emit(name, args, header, outputs, returns=None):
    """One njit function: cse over all outputs; outputs is [(target, expr)]."""
    exprs = [e for _, e in outputs] + list(returns or [])
    reps, reduced = sm.cse(exprs, symbols=sm.numbered_symbols("x"), optimizations="basic")
    lines = ["", "", "@njit(cache=True)", f"def {name}({', '.join(args)}):"]
    lines += ["    " + h for h in header]
    for sym, e in reps:
        lines.append(f"    {sym} = {_code(e)}")
    n_out = len(outputs)
    for (target, _), e in zip(outputs, reduced[:n_out], strict=True):
        lines.append(f"    {target} = {_code(e)}")
    if returns:
        lines.append("    return " + ", ".join(_code(e) for e in reduced[n_out:]))
    return "\n".join(lines), len(reps)


def emit(sym: dict) -> str:
    q = sym["q"]
    u = sym["u"]
    plain = {k: _plain(sym[k], q, u) for k in ("holonomic", "M", "f", "ke", "pe", "rates")}
    plain["front"] = [_plain(e, q, u) for e in sym["front"]]
    plain["nonholonomic"] = [_plain(e, q, u) for e in sym["nonholonomic"]]
    qs = [sm.Symbol(s.func.__name__) for s in q]
    us = [sm.Symbol(s.func.__name__) for s in u]
    q3, q4, q5, q7 = qs
    r = sym["r"]

    head_p = [f"{name} = p[{i}]" for i, name in enumerate(PARAMETERS)]
    head_u = [f"{s} = u[{i}]" for i, s in enumerate(us)]
    head_r = [f"{s} = r[{i}]" for i, s in enumerate(r)]

    def used(header, exprs):
        names = set()
        for e in exprs:
            names |= {str(s) for s in sm.sympify(e).free_symbols}
        return [h for h in header if h.split(" = ")[0] in names]

    blocks = []
    hol = plain["holonomic"]
    code, n = _emit(
        "holonomic",
        ["q4", "q5", "q7", "p"],
        used(head_p, [hol]),
        [],
        returns=[hol, hol.diff(q5)],
    )
    blocks.append(code)

    nh = sm.Matrix(plain["nonholonomic"])
    Ad = nh.jacobian(us[3:])
    Ai = nh.jacobian(us[:3])
    outs = [(f"Ad[{i}, {j}]", Ad[i, j]) for i in range(3) for j in range(3)]
    outs += [(f"Ai[{i}, {j}]", Ai[i, j]) for i in range(3) for j in range(3)]
    code, _ = _emit(
        "velocity_constraint",
        ["q4", "q5", "q7", "p", "Ad", "Ai"],
        used(head_p, [e for _, e in outs]),
        outs,
    )
    blocks.append(code)

    M, f = plain["M"], plain["f"]
    outs = [(f"M[{i}, {j}]", M[i, j]) for i in range(6) for j in range(6)]
    outs += [(f"f[{i}]", f[i]) for i in range(6)]
    exprs = [e for _, e in outs]
    code, n_mf = _emit(
        "mass_forcing",
        ["q4", "q5", "q7", "u", "p", "r", "M", "f"],
        used(head_p + head_u + head_r, exprs),
        outs,
    )
    blocks.append(code)

    G = f.jacobian(sm.Matrix(r))
    outs = [(f"G[{i}, {j}]", G[i, j]) for i in range(6) for j in range(4)]
    code, _ = _emit(
        "input_matrix",
        ["q4", "q5", "q7", "p", "G"],
        used(head_p, [e for _, e in outs]),
        outs,
    )
    blocks.append(code)

    ke, pe = plain["ke"], plain["pe"]
    code, _ = _emit(
        "energy",
        ["q4", "q5", "q7", "u", "p"],
        used(head_p + head_u, [ke, pe]),
        [],
        returns=[ke, pe],
    )
    blocks.append(code)

    outs = [(f"out[{i}]", e) for i, e in enumerate(list(plain["rates"]) + plain["front"])]
    code, _ = _emit(
        "contact",
        ["q3", "q4", "q5", "q7", "u", "p", "out"],
        used(head_p + head_u, [e for _, e in outs]),
        outs,
    )
    blocks.append(code)

    ud = [sm.Symbol(f"{s.func.__name__}d") for s in u]
    head_ud = [f"{s} = ud[{i}]" for i, s in enumerate(ud)]
    nr, nf = (_plain(e, q, u) for e in sym["contact_forces"])
    code, _ = _emit(
        "contact_forces",
        ["q4", "q5", "q7", "u", "ud", "p", "r"],
        used(head_p + head_u + head_ud + head_r, [nr, nf]),
        [],
        returns=[nr, nf],
    )
    blocks.append(code)

    outs = [(f"out[{i}]", _plain(e, q, u)) for i, e in enumerate(sym["momentum"])]
    code, _ = _emit(
        "momentum",
        ["q3", "q4", "q5", "q7", "u", "p", "out"],
        used(head_p + head_u, [e for _, e in outs]),
        outs,
    )
    blocks.append(code)

    header = [
        "# generated by scripts/derive_whipple.py; do not edit",
        '"""Whipple bicycle equations (Moore 2012 coordinates), emitted by',
        "scripts/derive_whipple.py from sympy KanesMethod (constraint_solver='CRAMER').",
        "",
        "See the script's docstring for coordinates, loads and the function contracts.",
        f"mass_forcing holds {n_mf} common subexpressions.",
        '"""',
        "",
        "import math  # noqa: F401",
        "",
        "from numba import njit",
        "",
        f"PARAMETERS = {PARAMETERS!r}",
        f"INPUTS = {INPUTS!r}",
    ]
    return "\n".join(header) + "\n".join(blocks) + "\n"


def lambdified(sym: dict) -> dict:
    """numpy functions of the same expressions via ``sympy.lambdify(cse=True)``.

    Used by the test that compares regenerated and committed code and by the
    benchmark of the lambdify + solve_ivp approach.  Signatures as the emitted
    functions but returning arrays: holonomic(q4, q5, q7, p) -> (h, dh),
    velocity_constraint(q4, q5, q7, p) -> (Ad, Ai), mass_forcing(q4, q5, q7, u, p, r)
    -> (M, f), energy(q4, q5, q7, u, p) -> (ke, pe), contact_forces(q4, q5, q7, u, ud,
    p, r) -> (N_R, N_F), momentum(q3, q4, q5, q7, u, p) -> (12,) list.
    """
    q = sym["q"]
    u = sym["u"]
    qs = [sm.Symbol(s.func.__name__) for s in q]
    us = [sm.Symbol(s.func.__name__) for s in u]
    _, q4, q5, q7 = qs
    par, r = list(sym["p"]), list(sym["r"])
    hol = _plain(sym["holonomic"], q, u)
    nh = sm.Matrix([_plain(e, q, u) for e in sym["nonholonomic"]])
    M, f = _plain(sym["M"], q, u), _plain(sym["f"], q, u)
    ke, pe = _plain(sym["ke"], q, u), _plain(sym["pe"], q, u)
    ud = [sm.Symbol(f"{s.func.__name__}d") for s in u]
    cf = [_plain(e, q, u) for e in sym["contact_forces"]]
    mom = [_plain(e, q, u) for e in sym["momentum"]]
    lam = sm.lambdify
    return {
        "contact_forces": lam((q4, q5, q7, us, ud, par, r), cf, cse=True),
        "momentum": lam((qs[0], q4, q5, q7, us, par), mom, cse=True),
        "holonomic": lam((q4, q5, q7, par), [hol, hol.diff(q5)], cse=True),
        "velocity_constraint": lam(
            (q4, q5, q7, par), [nh.jacobian(us[3:]), nh.jacobian(us[:3])], cse=True
        ),
        "mass_forcing": lam((q4, q5, q7, us, par, r), [M, f], cse=True),
        "energy": lam((q4, q5, q7, us, par), [ke, pe], cse=True),
    }


def check(sym: dict, n: int = 20, seed: int = 1) -> float:
    """Largest difference of the committed generated code from ``lambdified(sym)``.

    Evaluates every emitted function at ``n`` random states of the benchmark-like
    parameter vector of the committed module (imported from ``sim``; run from the
    repository with ``bikeid`` importable).  Differences are scaled by max(1, |value|).
    """
    import numpy as np

    from bikeid.sim import _whipple_generated as gen
    from bikeid.sim.nonlinear import parameter_vector
    from bikeid.sim.parameters import benchmark

    fresh = lambdified(sym)
    params = benchmark()
    p = parameter_vector(params, (0.4, -0.8))
    rng = np.random.default_rng(seed)
    worst = 0.0

    def diff(a, b):
        a, b = np.ravel(np.asarray(a, float)), np.ravel(np.asarray(b, float))
        return float(np.max(np.abs(a - b)) / max(1.0, float(np.max(np.abs(b)))))

    for _ in range(n):
        q3, q4, q7 = rng.uniform(-0.8, 0.8, size=3)
        q5 = params.lam + rng.uniform(-0.1, 0.1)
        u, ud, r = rng.normal(scale=3.0, size=6), rng.normal(size=6), rng.normal(size=4)
        Ad, Ai, M, f = np.empty((3, 3)), np.empty((3, 3)), np.empty((6, 6)), np.empty(6)
        gen.velocity_constraint(q4, q5, q7, p, Ad, Ai)
        gen.mass_forcing(q4, q5, q7, u, p, r, M, f)
        mom = np.empty(12)
        gen.momentum(q3, q4, q5, q7, u, p, mom)
        pairs = [
            (gen.holonomic(q4, q5, q7, p), fresh["holonomic"](q4, q5, q7, p)),
            ((Ad, Ai), fresh["velocity_constraint"](q4, q5, q7, p)),
            ((M, f), fresh["mass_forcing"](q4, q5, q7, u, p, r)),
            (gen.energy(q4, q5, q7, u, p), fresh["energy"](q4, q5, q7, u, p)),
            (
                gen.contact_forces(q4, q5, q7, u, ud, p, r),
                fresh["contact_forces"](q4, q5, q7, u, ud, p, r),
            ),
            (mom, fresh["momentum"](q3, q4, q5, q7, u, p)),
        ]
        for a, b in pairs:
            if isinstance(a, tuple) and isinstance(a[0], np.ndarray):
                worst = max([worst] + [diff(x, y) for x, y in zip(a, b, strict=True)])
            else:
                worst = max(worst, diff(a, b))
    return worst


def run(argv, *, description: str, target: Path, derive, emit, check) -> int:
    """Command line shared by the derivation scripts (this one and ``derive_arms.py``).

    Parameters
    ----------
    argv : list of str or None
        Arguments (None: ``sys.argv[1:]``).
    description : str
        The script's one-line description.
    target : Path
        Default output file (the committed generated module).
    derive, emit, check : callable
        ``derive() -> sym``, ``emit(sym) -> str`` (module text), ``check(sym) -> float``
        (largest relative difference between the committed module and ``sym``).

    Returns
    -------
    int
        Exit status: 0, or 1 when ``--check`` finds a difference above 1e-9.
    """
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--out", default=str(target), help="file to write")
    ap.add_argument(
        "--check",
        action="store_true",
        help=f"compare the committed {target.parent.name}/{target.name} with a fresh "
        "derivation (numerically, 1e-9 relative) instead of writing; exit 1 on a mismatch",
    )
    args = ap.parse_args(argv)
    try:  # before the minutes of derivation, not after
        out = check_output_path(args.out)
    except ValueError as exc:
        ap.error(str(exc))
    t0 = time.perf_counter()
    sym = derive()
    t1 = time.perf_counter()
    if args.check:
        worst = check(sym)
        ok = worst <= 1e-9
        print(f"largest relative difference {worst:.2e}: {'ok' if ok else 'STALE'}")
        return 0 if ok else 1
    text = emit(sym)
    t2 = time.perf_counter()
    atomic_write_text(out, text)
    print(
        f"derived in {t1 - t0:.1f} s, emitted in {t2 - t1:.1f} s: {out} ({len(text)} chars)",
        file=sys.stderr,
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    """Write sim/_whipple_generated.py, or ``--check`` it against a fresh derivation."""
    return run(
        argv, description=__doc__.splitlines()[0], target=TARGET, derive=derive, emit=emit,
        check=check,
    )  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
