"""Derive the linearized arm model (Whipple bicycle + the rider's arms) and emit plain code.

Run ``python scripts/derive_arms.py`` (one to three minutes) to regenerate
``sim/_arms_generated.py``; ``--check`` compares a fresh derivation with the committed
file numerically instead of writing it.

The model (Moore's dissertation, "Extensions", section "Rider Arms"; Moore & Hubbard's
"arm model"): the Whipple bicycle in Moore (2012) coordinates (frames N, A yaw q3, B roll
q4, C rear-frame pitch q5, E steer q7, as ``scripts/derive_whipple.py``) plus four arm
segments, right/left upper arm and lower arm (forearm with hand).  Shoulders are fixed in
the rear frame C (the rider's torso belongs to it), the hands are held at grip points fixed
in the front frame E, the elbows are hinges and the elbow axis of each arm is kept
perpendicular to b3 (the ground normal of the roll frame: the arms "hang down", the
dissertation's eq. "ArmsDown").  These eight holonomic constraints remove the arms' eight
extra freedoms, so the model keeps three coordinates (roll, steer, pitch dependent) and two
independent lateral speeds with the steer torque as input.

Linearized early (the full nonlinear Kane derivation with eight more dependent
coordinates is not needed for the linear equations):

1. Arm kinematics in closed form.  With shoulder S (in C) and grip G(q7) (in E), the elbow
   lies in the plane through S and G that contains b3 (its normal, the elbow axis, is
   k x (G - S) with k = b3), below the line S-G, at distances a (upper arm) and b (lower
   arm): E = S + x e + y m with e = (G-S)/L, m = e x n, x = (a^2 - b^2 + L^2)/(2L),
   y = sqrt(a^2 - x^2).  Each segment's mass-centre position in C, relative to the rear
   wheel centre, is thus an explicit function p(q7, q5) (q5 enters through b3 in C); its
   Taylor coefficients at the upright (q7 = 0, q5 = lam) are emitted by ``arm_segments``:
   p0, dp/dq7, d2p/dq7^2, dp/dq5, the segment axis and the segment's angular velocity
   relative to C per unit steer rate (w, from dR/dq7 R^T, R = [n x axis, n, axis]).
2. A generic extra body whose mass-centre position in C is p(q7, q5) (second-order Taylor
   polynomial with those coefficients) and whose angular velocity is omega_C + q7' w, with
   a constant inertia (its nominal value, C axes): ``body_matrices`` emits its linear
   contribution to M, C1, K0, K2 (Meijaard rows/columns [phi, delta]) using the Whipple
   model's own kinematics: the dependent speeds (yaw u3, pitch u5, front wheel u8) solved
   from the front contact's velocity constraint to first order about upright straight
   running at v = -rr u6, the generalized inertia forces of the roll and steer speeds
   (m a . v_r + I alpha . omega_r to first order; the nominal motion has no acceleration),
   and gravity through the Hessian of the potential on the constraint surface,
   V_qq + V_q5 d2q5/dq^2 (the pitch's curvature from the holonomic constraint).
   Coefficients of u4', u7' give M, of u4, u7 (/v) C1, of q4, q7 (/v^2) K2; the potential
   Hessian / g gives K0.  Orders needed: positions to second order (gravity), velocities
   and orientation to first/zeroth order (d2p/dq7^2 and dp/dq5 enter only the potential;
   the inertia's change with q7 multiplies zero nominal angular motion).

Geometry parameters ``geo = [w, c, lam, rR, rF, g]`` (Meijaard notation; Moore's d1, d2, d3
follow from them so that the upright pitch is exactly lam).  Body vector (C axes, rear wheel
centre origin, SI units): ``[m, Ixx, Iyy, Izz, Ixy, Iyz, Ixz, p0(3), pd(3), pdd(3), pt(3),
w(3)]``.  Arm vector (benchmark axes at the upright: x forward of the rear contact, y right,
z down): ``[xs, ys, zs, xg, yg, zg, a, b, l5, l6]``: shoulder, grip, upper arm length
(shoulder-elbow), lower arm length (elbow-grip), mass-centre distances from shoulder and
elbow; the left arm is the right one with ys, yg negated.

Emitted functions (plain Python + math):

- ``body_matrices(geo, body) -> (M, C1, K0, K2, coupling)``: 2x2 nested lists and the
  coefficients of the forward-speed perturbation (u6', u6 - u6_0) in the roll and steer
  rows (zero for a body symmetric about the bicycle's mid-plane);
- ``arm_segments(geo, arm) -> (upper, lower)``: each a 18-list p0, pd, pdd, pt, axis, w.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.util
import sys
from pathlib import Path

import sympy as sm
import sympy.physics.mechanics as me

ROOT = Path(__file__).resolve().parents[1]
TARGET = ROOT / "sim" / "_arms_generated.py"

GEOMETRY = ("w", "c", "lam", "rR", "rF", "g")
BODY = (
    "m", "Ixx", "Iyy", "Izz", "Ixy", "Iyz", "Ixz",
    "p0x", "p0y", "p0z", "pdx", "pdy", "pdz", "pddx", "pddy", "pddz",
    "ptx", "pty", "ptz", "wx", "wy", "wz",
)  # fmt: skip
ARM = ("xs", "ys", "zs", "xg", "yg", "zg", "a", "b", "l5", "l6")
SEGMENT = (
    "p0x", "p0y", "p0z", "pdx", "pdy", "pdz", "pddx", "pddy", "pddz",
    "ptx", "pty", "ptz", "ax", "ay", "az", "wx", "wy", "wz",
)  # fmt: skip


@functools.cache
def _whipple():
    """``derive_whipple.py`` as a module (its code printer and command line are reused)."""
    spec = importlib.util.spec_from_file_location(
        "derive_whipple", Path(__file__).with_name("derive_whipple.py")
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _moore(G):
    """Moore's d1, d2, d3 from the benchmark geometry (as BicycleParameters.to_moore)."""
    w, c, lam, rR, rF = G["w"], G["c"], G["lam"], G["rR"], G["rF"]
    cl, sl = sm.cos(lam), sm.sin(lam)
    d1 = cl * (c + w - rR * sm.tan(lam))
    d3 = -cl * (c - rF * sm.tan(lam))
    d2 = (rR + d1 * sl - rF + d3 * sl) / cl
    return d1, d2, d3


def derive_body() -> dict:
    """Linear contribution of a generic extra body (module docstring, step 2)."""
    t = me.dynamicsymbols._t
    q3, q4, q5, q6, q7, q8 = me.dynamicsymbols("q3:9")
    u3, u4, u5, u6, u7, u8 = me.dynamicsymbols("u3:9")
    geo = sm.symbols(GEOMETRY, real=True)
    G = dict(zip(GEOMETRY, geo, strict=True))
    body = sm.symbols(BODY, real=True)
    Bd = dict(zip(BODY, body, strict=True))
    v = sm.Symbol("v", real=True)
    d1, d2, d3 = _moore(G)
    rR, rF, lam = G["rR"], G["rF"], G["lam"]

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

    dn = me.Point("dn")
    dn.set_vel(N, 0)
    do = dn.locatenew("do", -rR * B.z)
    ce = do.locatenew("ce", d1 * C.x)
    fo = ce.locatenew("fo", d2 * E.z + d3 * E.x)
    down = me.cross(E.y, me.cross(A.z, E.y))
    fn = fo.locatenew("fn", rF * down / sm.sqrt(down.dot(down)))
    do.v2pt_theory(dn, N, D)
    ce.v2pt_theory(do, N, C)
    fo.v2pt_theory(ce, N, E)
    fn.v2pt_theory(fo, N, Fw)

    qs = sm.symbols("q4 q5 q7", real=True)
    plain_q = dict(zip((q4, q5, q7), qs, strict=True))
    nominal = {qs[0]: 0, qs[1]: lam, qs[2]: 0}

    # dependent speeds to first order (front contact point of the wheel at rest)
    vfn = fn.vel(N)
    nh = sm.Matrix([vfn.dot(A.x), vfn.dot(A.y), vfn.dot(A.z)]).xreplace(plain_q)
    udep, uind = [u3, u5, u8], [u4, u6, u7]
    Ad, Ai = nh.jacobian(udep), nh.jacobian(uind)
    Ad0, Ai0 = Ad.subs(nominal), Ai.subs(nominal)
    u60 = -v / rR
    uind0 = sm.Matrix([0, u60, 0])
    Ad0inv = Ad0.inv()
    J = -Ad0inv * Ai0  # d udep / d uind at the nominal
    udep0 = J * uind0
    dq = {}
    for qk in (qs[0], qs[2]):
        dq[qk] = -Ad0inv * (Ai.diff(qk).subs(nominal) * uind0 + Ad.diff(qk).subs(nominal) * udep0)
    uind_vec = sm.Matrix(uind)
    udep_lin = udep0 + J * (uind_vec - uind0) + dq[qs[0]] * q4 + dq[qs[2]] * q7
    kd = {
        qi.diff(t): ui
        for qi, ui in zip((q3, q4, q5, q6, q7, q8), (u3, u4, u5, u6, u7, u8), strict=True)
    }
    udep_lin_d = udep_lin.diff(t).xreplace(kd)

    # the extra body
    p0 = sm.Matrix([Bd["p0x"], Bd["p0y"], Bd["p0z"]])
    pd = sm.Matrix([Bd["pdx"], Bd["pdy"], Bd["pdz"]])
    pdd = sm.Matrix([Bd["pddx"], Bd["pddy"], Bd["pddz"]])
    pt = sm.Matrix([Bd["ptx"], Bd["pty"], Bd["ptz"]])
    pc = p0 + pd * q7 + pdd * q7**2 / 2 + pt * (q5 - lam)
    pvec = pc[0] * C.x + pc[1] * C.y + pc[2] * C.z
    wvec = Bd["wx"] * C.x + Bd["wy"] * C.y + Bd["wz"] * C.z
    vP = (do.vel(N) + pvec.dt(N)).xreplace(kd)
    omega = C.ang_vel_in(N) + u7 * wvec
    aP = vP.dt(N).xreplace(kd)
    alpha = omega.dt(N).xreplace(kd)

    rep_d = {ud.diff(t): e for ud, e in zip(udep, udep_lin_d, strict=True)}
    rep = dict(zip(udep, udep_lin, strict=True))
    uds = sm.symbols("u4d u6d u7d", real=True)
    us = sm.symbols("u4 u6 u7", real=True)
    plain_u = {u4.diff(t): uds[0], u6.diff(t): uds[1], u7.diff(t): uds[2]}
    plain_u.update(dict(zip(uind, us, strict=True)))

    def lin_ready(mat):
        return mat.xreplace(rep_d).xreplace(rep).xreplace(plain_u).xreplace(plain_q)

    aA = lin_ready(aP.to_matrix(A))
    alC = lin_ready(alpha.to_matrix(C))
    # partial velocities at the nominal (dependent speeds through J)
    vA = vP.to_matrix(A).xreplace(plain_q)
    wC = omega.to_matrix(C).xreplace(plain_q)
    part_v, part_w = [], []
    for r in (0, 2):  # u4, u7
        pv = vA.diff(uind[r]) + sum((vA.diff(udep[k]) * J[k, r] for k in range(3)), sm.zeros(3, 1))
        pw = wC.diff(uind[r]) + sum((wC.diff(udep[k]) * J[k, r] for k in range(3)), sm.zeros(3, 1))
        part_v.append(pv.subs(nominal))
        part_w.append(pw.subs(nominal))

    Ic = sm.Matrix(
        [
            [Bd["Ixx"], Bd["Ixy"], Bd["Ixz"]],
            [Bd["Ixy"], Bd["Iyy"], Bd["Iyz"]],
            [Bd["Ixz"], Bd["Iyz"], Bd["Izz"]],
        ]
    )
    # first-order variables and the nominal values of everything
    lin_vars = (qs[0], qs[2], us[0], us[2], uds[0], uds[2], uds[1], us[1])
    point = {qs[0]: 0, qs[1]: lam, qs[2]: 0, us[0]: 0, us[1]: u60, us[2]: 0}
    point.update({uds[0]: 0, uds[1]: 0, uds[2]: 0})
    M, C1, K2 = sm.zeros(2, 2), sm.zeros(2, 2), sm.zeros(2, 2)
    coupling = sm.zeros(2, 2)  # rows roll/steer, columns u6', u6 - u60
    for r in range(2):
        expr = Bd["m"] * aA.dot(part_v[r]) + (Ic * alC).dot(part_w[r])
        co = {x: sm.expand(expr.diff(x).subs(point)) for x in lin_vars}
        M[r, 0], M[r, 1] = co[uds[0]], co[uds[2]]
        C1[r, 0], C1[r, 1] = (sm.expand(co[us[0]] / v), sm.expand(co[us[2]] / v))
        K2[r, 0], K2[r, 1] = (sm.expand(co[qs[0]] / v**2), sm.expand(co[qs[2]] / v**2))
        coupling[r, 0], coupling[r, 1] = co[uds[1]], co[us[1]]

    # gravity: potential on the constraint surface
    hol = fn.pos_from(dn).dot(A.z).xreplace(plain_q)
    height = -(pvec - rR * B.z).dot(A.z).xreplace(plain_q)  # above the ground
    V = Bd["m"] * G["g"] * height
    h5 = hol.diff(qs[1]).subs(nominal)
    V5 = V.diff(qs[1]).subs(nominal)
    K0 = sm.zeros(2, 2)
    idx = (qs[0], qs[2])
    for i in range(2):
        for j in range(2):
            curv = -hol.diff(idx[i], idx[j]).subs(nominal) / h5
            K0[i, j] = (V.diff(idx[i], idx[j]).subs(nominal) + V5 * curv) / G["g"]
    return {
        "geo": geo,
        "body": body,
        "M": M,
        "C1": C1,
        "K0": K0,
        "K2": K2,
        "coupling": coupling,
        "first_slope": [hol.diff(x).subs(nominal) for x in idx],
    }


def derive_arm() -> dict:
    """Closed-form arm kinematics and their Taylor coefficients (module docstring, step 1)."""
    geo = sm.symbols(GEOMETRY, real=True)
    G = dict(zip(GEOMETRY, geo, strict=True))
    arm = sm.symbols(ARM, real=True)
    P = dict(zip(ARM, arm, strict=True))
    d1, _, _ = _moore(G)
    lam, rR = G["lam"], G["rR"]
    q5, q7 = sm.symbols("q5 q7", real=True)
    cl, sl = sm.cos(lam), sm.sin(lam)

    def to_c(x, y, z):  # benchmark point at the upright -> C axes about the rear wheel centre
        return sm.Matrix([x * cl - (z + rR) * sl, y, x * sl + (z + rR) * cl])

    S = to_c(P["xs"], P["ys"], P["zs"])
    g0 = to_c(P["xg"], P["yg"], P["zg"])
    axis_pt = sm.Matrix([d1, 0, 0])  # the steer axis (C3) through ce
    Rz = sm.Matrix([[sm.cos(q7), -sm.sin(q7), 0], [sm.sin(q7), sm.cos(q7), 0], [0, 0, 1]])
    grip = axis_pt + Rz * (g0 - axis_pt)
    # b3 in C axes: C is B rotated by q5 about B2
    k = sm.Matrix([-sm.sin(q5), 0, sm.cos(q5)])
    d = grip - S
    L = sm.sqrt(d.dot(d))
    e = d / L
    n = k.cross(d)
    n = n / sm.sqrt(n.dot(n))
    m = e.cross(n)
    x = (P["a"] ** 2 - P["b"] ** 2 + L**2) / (2 * L)
    y = sm.sqrt(P["a"] ** 2 - x**2)
    elbow = S + x * e + y * m
    up_axis = (elbow - S) / P["a"]
    lo_axis = (grip - elbow) / P["b"]
    segs = []
    for start, ax, l_cm in ((S, up_axis, P["l5"]), (elbow, lo_axis, P["l6"])):
        pos = start + l_cm * ax
        R = sm.Matrix.hstack(n.cross(ax), n, ax)
        W = R.diff(q7) * R.T
        wv = sm.Matrix([W[2, 1], W[0, 2], W[1, 0]])
        at = {q7: 0, q5: lam}
        out = [
            *pos.subs(at),
            *pos.diff(q7).subs(at),
            *pos.diff(q7, 2).subs(at),
            *pos.diff(q5).subs(at),
            *ax.subs(at),
            *wv.subs(at),
        ]
        segs.append(out)
    return {"geo": geo, "arm": arm, "upper": segs[0], "lower": segs[1]}


def derive() -> dict:
    """Both derivations."""
    return {"body": derive_body(), "arm": derive_arm()}


def _function(code, name, args, unpack, outputs, ret):
    exprs = [e for _, e in outputs]
    reps, reduced = sm.cse(exprs, symbols=sm.numbered_symbols("x"), optimizations="basic")
    names = set()
    for e in list(reduced) + [r for _, r in reps]:
        names |= {str(s) for s in sm.sympify(e).free_symbols}
    lines = ["", "", f"def {name}({', '.join(args)}):"]
    for vec, syms in unpack:
        for i, s in enumerate(syms):
            if str(s) in names:
                lines.append(f"    {s} = {vec}[{i}]")
    for sym, e in reps:
        lines.append(f"    {sym} = {code(e)}")
    for (target, _), e in zip(outputs, reduced, strict=True):
        lines.append(f"    {target} = {code(e)}")
    lines.append(f"    return {ret}")
    return "\n".join(lines), len(reps)


def provenance(code: str) -> str:
    """The header line naming what made ``code``: SHA-256 of the two derivation scripts
    (this one and ``derive_whipple.py``, whose printer and kinematics it reuses) and of
    ``code`` itself (the emitted functions), so a stale or hand-edited module is found
    without the minutes of a fresh derivation."""
    here = Path(__file__).resolve()
    digests = [
        f"{f.name} {hashlib.sha256(f.read_bytes()).hexdigest()[:16]}"
        for f in (here, here.with_name("derive_whipple.py"))
    ]
    digests.append(f"code {hashlib.sha256(code.encode()).hexdigest()[:16]}")
    return "# sha256: " + ", ".join(digests)


def emitted_code(text: str) -> str:
    """The emitted functions of a generated module's text (all from the first ``def``)."""
    return text[text.index("\n\n\ndef ") + 1 :]


def emit(sym: dict) -> str:
    """The text of ``sim/_arms_generated.py``."""
    code = _whipple()._code  # same formatting of powers
    b = sym["body"]
    outs = []
    for nm in ("M", "C1", "K0", "K2", "coupling"):
        for i in range(2):
            for j in range(2):
                outs.append((f"{nm}_{i}{j}", b[nm][i, j]))
    ret = ", ".join(
        f"[[{nm}_00, {nm}_01], [{nm}_10, {nm}_11]]" for nm in ("M", "C1", "K0", "K2", "coupling")
    )
    body_code, n_body = _function(
        code, "body_matrices", ["geo", "body"],
        [("geo", b["geo"]), ("body", b["body"])], outs, f"({ret})",
    )  # fmt: skip
    a = sym["arm"]
    outs = [(f"up[{i}]", e) for i, e in enumerate(a["upper"])]
    outs += [(f"lo[{i}]", e) for i, e in enumerate(a["lower"])]
    arm_code, n_arm = _function(
        code, "arm_segments", ["geo", "arm"],
        [("geo", a["geo"]), ("arm", a["arm"])],
        outs, "up, lo",
    )  # fmt: skip
    arm_code = arm_code.replace(
        "def arm_segments(geo, arm):",
        "def arm_segments(geo, arm):\n    up = [0.0] * 18\n    lo = [0.0] * 18",
    )
    code = body_code + arm_code + "\n"
    header = [
        "# generated by scripts/derive_arms.py; do not edit",
        provenance(code),
        "# ruff: noqa: E501",
        '"""Linearized arm model pieces, emitted by scripts/derive_arms.py (sympy).',
        "",
        "See the script's docstring for the model, the argument vectors and the outputs.",
        f"body_matrices holds {n_body}, arm_segments {n_arm} common subexpressions.",
        '"""',
        "",
        "import math  # noqa: F401",
        "",
        f"GEOMETRY = {GEOMETRY!r}",
        f"BODY = {BODY!r}",
        f"ARM = {ARM!r}",
        f"SEGMENT = {SEGMENT!r}",
    ]
    return "\n".join(header) + "\n" + code


def lambdified(sym: dict) -> dict:
    """numpy functions of the same expressions (``sympy.lambdify``), same signatures."""
    b, a = sym["body"], sym["arm"]
    geo, body, arm = list(b["geo"]), list(b["body"]), list(a["arm"])
    mats = [b[nm] for nm in ("M", "C1", "K0", "K2", "coupling")]
    return {
        "body_matrices": sm.lambdify((geo, body), mats, cse=True),
        "arm_segments": sm.lambdify((list(a["geo"]), arm), [a["upper"], a["lower"]], cse=True),
    }


def check(sym: dict, n: int = 10, seed: int = 1) -> float:
    """Largest difference of the committed generated code from ``lambdified(sym)``.

    Evaluated at ``n`` random body vectors and at arm vectors near the default arms on the
    benchmark geometry (``bikeid`` importable); differences scaled by max(1, |value|).
    """
    import numpy as np

    from bikeid.sim import _arms_generated as gen
    from bikeid.sim.arm_model import ArmParameters, geometry_vector
    from bikeid.sim.parameters import benchmark

    fresh = lambdified(sym)
    geo = geometry_vector(benchmark())
    rng = np.random.default_rng(seed)
    worst = 0.0
    for _ in range(n):
        body = rng.normal(size=len(BODY))
        got = np.array(gen.body_matrices(geo, body), float)
        ref = np.array(fresh["body_matrices"](geo, body), float)
        worst = max(worst, float(np.max(np.abs(got - ref)) / max(1.0, np.max(np.abs(ref)))))
        arm = ArmParameters().arm_vector() * (1 + 0.02 * rng.normal(size=len(ARM)))
        got = np.array(gen.arm_segments(geo, arm), float)
        ref = np.array(fresh["arm_segments"](geo, arm), float)
        worst = max(worst, float(np.max(np.abs(got - ref)) / max(1.0, np.max(np.abs(ref)))))
    return worst


def main(argv: list[str] | None = None) -> int:
    """Write sim/_arms_generated.py, or ``--check`` it against a fresh derivation."""
    return _whipple().run(
        argv, description=__doc__.splitlines()[0], target=TARGET, derive=derive, emit=emit,
        check=check,
    )  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
