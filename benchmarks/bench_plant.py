"""Performance of the nonlinear plant: RHS cost, closed-loop runs, lambdify and pydy-Cython peers.

Run: ``python benchmarks/bench_plant.py [--repeat 5] [--peer-duration 10]``
(about 45 s on 2 loaded cores, of which ~16 s is the pydy/Cython build; prints a
Markdown table for docs/nonlinear.md and docs/performance.md).

Measured:
1. numba compile time, cold (empty cache dir) and warm (cached), in subprocesses;
2. one right-hand-side evaluation (pitch Newton + constraints + 6x6 solve), timed
   in a compiled loop and as a Python call;
3. 50 s closed loop at 5 m/s, T_delta = 10 phidot (Python controller, 10 ms ZOH),
   default step (2 RK4 substeps), median wall time of repeats, and its max error
   against the DOP853 rtol=1e-12 reference;
4. the peer approach: the same sympy equations through ``lambdify(cse=True)``
   (numpy; Newton pitch, numpy.linalg.solve) and ``scipy.integrate.solve_ivp``
   (RK45, restarted every controller sample so the ZOH is the same), with the
   loosest rtol (atol = rtol/100) whose error is no larger than ours; time per
   simulated second;
5. the second peer: the same expressions compiled by pydy's Cython code generator
   (``pydy.codegen.cython_code.CythonMatrixGenerator``: C with common subexpressions
   plus a Cython wrapper, three modules), driven by the same Newton pitch, constraint
   solve and ``solve_ivp`` loop as peer 4 but with preallocated buffers; build time,
   one RHS, its agreement with the lambdified RHS, and the same closed-loop timing.
   If pydy or the C build fails, the table says "could not build: <reason>".
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bikeid.sim.integrate import simulate, simulate_reference
from bikeid.sim.nonlinear import WhippleBicycle, rhs
from bikeid.sim.parameters import benchmark

#: The repository, for the symbolic derivation (``scripts/derive_whipple.py``), which is a
#: development tool and not part of the installed package; the plant is always imported
#: from the installed ``bikeid``.
ROOT = Path(__file__).resolve().parents[1]

V, K = 5.0, 10.0


def controller(t, y):
    return K * y[4]


def compile_times() -> tuple[float, float]:
    code = (
        "import time; t0 = time.perf_counter();"
        "from bikeid.sim.nonlinear import WhippleBicycle; from bikeid.sim.integrate import "
        "simulate; from bikeid.sim.parameters import benchmark; b = WhippleBicycle(benchmark());"
        "simulate(b, b.state(5.0), 0.1, controller=lambda t, y: 0.0);"
        "print(time.perf_counter() - t0)"
    )
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        out = []
        for _ in range(2):  # cold, then warm from the cache just written
            res = subprocess.run(
                [sys.executable, "-c", code], env=env, capture_output=True, text=True
            )
            if res.returncode:
                raise RuntimeError(res.stderr)
            out.append(float(res.stdout.strip().splitlines()[-1]))
    return out[0], out[1]


def rhs_time(bike: WhippleBicycle, n: int = 200_000) -> tuple[float, float]:
    from numba import njit

    @njit(cache=False)
    def loop(n, y, q5g, p, r, ev, yd):
        s = 0.0
        for i in range(n):
            y[3] = 0.01 * (i % 7)
            s += rhs(y, q5g, p, r, ev, False, yd) + yd[7]
        return s

    y = bike.state(V, phi=0.05, deltadot=0.1)
    q5g = np.array([bike.lam])
    r, ev, yd = np.zeros(4), np.array([0.0, 0.0, 1.0, 0.0]), np.empty(10)
    loop(10, y, q5g, bike.p, r, ev, yd)
    reps = []
    for _ in range(5):
        t0 = time.perf_counter()
        loop(n, y, q5g, bike.p, r, ev, yd)
        reps.append((time.perf_counter() - t0) / n)
    m = 20_000
    t0 = time.perf_counter()
    for _ in range(m):
        rhs(y, q5g, bike.p, r, ev, False, yd)
    return statistics.median(reps), (time.perf_counter() - t0) / m


def load_derivation():
    """``scripts/derive_whipple.py`` as a module, its symbolic result, derivation time [s]."""
    spec = importlib.util.spec_from_file_location(
        "derive_whipple", ROOT / "scripts" / "derive_whipple.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    t0 = time.perf_counter()
    sym = mod.derive()
    return mod, sym, time.perf_counter() - t0


class Peer:
    """Same equations, lambdified numpy functions, solve_ivp between samples."""

    def __init__(self, bike: WhippleBicycle, mod, sym, t_derive: float):
        t0 = time.perf_counter()
        self.fn = mod.lambdified(sym)
        self.setup = t_derive + time.perf_counter() - t0
        self.p = bike.p
        self.q5 = bike.lam

    def rhs(self, t, x, Td):
        # x = [q3, q4, q7, u4, u6, u7]
        q4, q7 = x[1], x[2]
        q5 = self.q5
        for _ in range(40):
            h, dh = self.fn["holonomic"](q4, q5, q7, self.p)
            step = h / dh
            q5 -= step
            if abs(step) < 1e-12:
                break
        self.q5 = q5
        Ad, Ai = self.fn["velocity_constraint"](q4, q5, q7, self.p)
        ui = x[3:6]
        ud = np.linalg.solve(np.asarray(Ad, float), -np.asarray(Ai, float) @ ui)
        u = np.concatenate([ui, ud])
        M, f = self.fn["mass_forcing"](q4, q5, q7, u, self.p, [Td, 0.0, 0.0, 0.0])
        udot = np.linalg.solve(np.asarray(M, float), np.ravel(np.asarray(f, float)))
        return np.array([ud[0], ui[0], ui[2], udot[0], udot[1], udot[2]])

    def run(self, x0, duration, rtol, atol, dt=0.01):
        from scipy.integrate import solve_ivp

        x = np.array([x0[2], x0[3], x0[5], x0[7], x0[8], x0[9]])
        n = int(round(duration / dt))
        out = np.empty((n + 1, 6))
        out[0] = x
        for k in range(n):
            Td = K * x[3]
            sol = solve_ivp(self.rhs, (0.0, dt), x, method="RK45", rtol=rtol, atol=atol,
                            args=(Td,))  # fmt: skip
            x = sol.y[:, -1]
            out[k + 1] = x
        return out


class CythonPeer(Peer):
    """The lambdify peer's algorithm on pydy ``CythonMatrixGenerator`` functions.

    The expressions are exactly those of ``derive_whipple.lambdified`` (holonomic
    residual and its q5 derivative; the constraint Jacobians Ad, Ai; the 6x6 mass
    matrix and forcing of Kane's equations in u = [u4, u6, u7, u3, u5, u8]).  Each
    compiled ``eval`` fills preallocated flat float64 buffers (pydy's calling convention).
    """

    def __init__(self, bike: WhippleBicycle, mod, sym, t_derive: float):
        import sympy as sm
        from pydy.codegen.cython_code import CythonMatrixGenerator

        t0 = time.perf_counter()
        q, u = sym["q"], sym["u"]
        _, q4, q5, q7 = (sm.Symbol(s.func.__name__) for s in q)
        us = [sm.Symbol(s.func.__name__) for s in u]
        par, r = list(sym["p"]), list(sym["r"])
        hol = mod._plain(sym["holonomic"], q, u)
        nh = sm.Matrix([mod._plain(e, q, u) for e in sym["nonholonomic"]])
        M, f = mod._plain(sym["M"], q, u), mod._plain(sym["f"], q, u)
        qa = [q4, q5, q7]

        def build(prefix, args, mats):
            return CythonMatrixGenerator(args, mats, prefix=prefix, cse=True).compile()

        self._hol = build("bikeid_hol", [qa, par], [sm.Matrix([hol, hol.diff(q5)])])
        self._vc = build("bikeid_vc", [qa, par], [nh.jacobian(us[3:]), nh.jacobian(us[:3])])
        self._mf = build("bikeid_mf", [qa, us, par, r], [M, f])
        self.setup = t_derive + time.perf_counter() - t0
        self.p = np.ascontiguousarray(bike.p, dtype=float)
        self.q5 = bike.lam
        self._q, self._h = np.zeros(3), np.zeros(2)
        self._Ad, self._Ai = np.zeros(9), np.zeros(9)
        self._u, self._r = np.zeros(6), np.zeros(4)
        self._M, self._f = np.zeros(36), np.zeros(6)

    def rhs(self, t, x, Td):
        qa, h = self._q, self._h
        qa[0], qa[2] = x[1], x[2]
        q5 = self.q5
        for _ in range(40):
            qa[1] = q5
            self._hol(qa, self.p, h)
            step = h[0] / h[1]
            q5 -= step
            if abs(step) < 1e-12:
                break
        self.q5 = qa[1] = q5
        self._vc(qa, self.p, self._Ad, self._Ai)
        ui = x[3:6]
        ud = np.linalg.solve(self._Ad.reshape(3, 3), -self._Ai.reshape(3, 3) @ ui)
        u = self._u
        u[:3], u[3:] = ui, ud
        self._r[0] = Td
        self._mf(qa, u, self.p, self._r, self._M, self._f)
        udot = np.linalg.solve(self._M.reshape(6, 6), self._f)
        return np.array([ud[0], ui[0], ui[2], udot[0], udot[1], udot[2]])


def build_failure(exc: BaseException) -> str:
    """One line saying why the pydy Cython peer did not build (compiler output if any)."""
    cause = exc.__cause__ or exc.__context__
    out = getattr(cause, "output", None)
    if out:
        lines = [ln for ln in out.decode(errors="replace").splitlines() if ln.strip()]
        return f"{exc} ({lines[-1].strip()})"
    return f"{type(exc).__name__}: {exc}"


def rhs_us(peer: Peer, xp: np.ndarray, m: int = 2000) -> float:
    """Mean wall time of one peer RHS evaluation called from Python [us]."""
    peer.rhs(0.0, xp, 0.0)
    t0 = time.perf_counter()
    for _ in range(m):
        peer.rhs(0.0, xp, 0.0)
    return (time.perf_counter() - t0) / m * 1e6


def peer_closed_loop(peer: Peer, x0, D: float, ref_sig: np.ndarray, target: float):
    """Loosest RK45 rtol whose max error vs the reference is <= target: (rtol, wall, error)."""
    for rtol in (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8):
        t0 = time.perf_counter()
        out = peer.run(x0, D, rtol=rtol, atol=rtol * 1e-2)
        wall = time.perf_counter() - t0
        err = float(np.max(np.abs(out - ref_sig)))
        if err <= target:
            break
    return rtol, wall, err


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--peer-duration", type=float, default=10.0)
    args = ap.parse_args(argv)

    rows = []
    cold, warm = compile_times()
    rows.append(("numba compile + first 0.1 s run, cold cache [s]", f"{cold:.1f}"))
    rows.append(("same, warm cache (cache=True) [s]", f"{warm:.2f}"))

    bike = WhippleBicycle(benchmark())
    t_loop, t_py = rhs_time(bike)
    rows.append(("one RHS evaluation, compiled loop [us]", f"{t_loop * 1e6:.2f}"))
    rows.append(("one RHS evaluation, called from Python [us]", f"{t_py * 1e6:.2f}"))

    x0 = bike.state(V, phi=math.radians(5.0), phidot=0.3, deltadot=-0.2)
    simulate(bike, x0, 0.1, controller=controller)
    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        tr = simulate(bike, x0, 50.0, controller=controller)
        times.append(time.perf_counter() - t0)
    t_ours = statistics.median(times)
    t0 = time.perf_counter()
    ref = simulate_reference(bike, x0, 50.0, controller=controller)
    t_ref = time.perf_counter() - t0
    err = float(np.max(np.abs(tr.y - ref.y)))
    rows.append(("50 s closed loop at 5 m/s, default step, median wall [s]", f"{t_ours:.3f}"))
    rows.append(("  ... min / max of repeats [s]", f"{min(times):.3f} / {max(times):.3f}"))
    rows.append(("  ... max error vs DOP853 rtol=1e-12 reference (all 8 signals)", f"{err:.1e}"))
    rows.append(("reference (DOP853, numba RHS) for 50 s [s]", f"{t_ref:.1f}"))

    mod, sym, t_derive = load_derivation()
    peer = Peer(bike, mod, sym, t_derive)
    rows.append(("peer: sympy derivation + lambdify(cse=True) setup [s]", f"{peer.setup:.1f}"))
    xp = np.array([0.0, 0.05, 0.02, 0.1, -V / bike.rR, 0.1])
    rows.append(("peer: one lambdified RHS evaluation [us]", f"{rhs_us(peer, xp):.0f}"))
    D = args.peer_duration
    n = int(round(D / 0.01)) + 1
    ref_sig = np.column_stack([ref.y[:n, i] for i in (3, 1, 2, 4, 7, 5)])  # q3 q4 q7 u4 u6 u7
    ours_D = float(np.max(np.abs(tr.y[:n] - ref.y[:n])))
    per_s_ours = t_ours / 50.0
    rtol, t_peer, e_peer = peer_closed_loop(peer, x0, D, ref_sig, ours_D)
    per_s_peer = t_peer / D
    rows.append((f"peer: RK45 rtol={rtol:g}, {D:g} s simulated, wall [s]", f"{t_peer:.2f}"))
    rows.append(("  ... its max error vs reference (ours over the same span)",
                 f"{e_peer:.1e} ({ours_D:.1e})"))  # fmt: skip
    rows.append(("wall per simulated second: peer / ours [ms]",
                 f"{per_s_peer * 1e3:.1f} / {per_s_ours * 1e3:.2f}"))  # fmt: skip
    rows.append(("speed-up (peer / ours per simulated second)", f"{per_s_peer / per_s_ours:.0f}x"))

    peers = [("lambdify peer", per_s_peer, e_peer)]
    try:
        cy = CythonPeer(bike, mod, sym, t_derive)
    except Exception as exc:  # noqa: BLE001 - any build failure is a result to report
        rows.append(("pydy Cython peer", f"could not build: {build_failure(exc)}"))
        cy = None
    if cy is not None:
        rows.append(("pydy Cython peer: derivation + CythonMatrixGenerator build of 3 modules [s]",
                     f"{cy.setup:.1f}"))  # fmt: skip
        xd = np.array([0.3, 0.1, -0.2, 0.4, -V / bike.rR + 0.5, -0.6])  # a rolled, steered state
        a, b = cy.rhs(0.0, xd, 2.0), peer.rhs(0.0, xd, 2.0)
        rows.append(("  ... max |RHS difference| vs the lambdified RHS, relative to max |RHS|",
                     f"{np.max(np.abs(a - b)) / np.max(np.abs(b)):.1e}"))  # fmt: skip
        rows.append(("pydy Cython peer: one RHS evaluation [us]", f"{rhs_us(cy, xp):.1f}"))
        rtol_c, t_cy, e_cy = peer_closed_loop(cy, x0, D, ref_sig, ours_D)
        per_s_cy = t_cy / D
        rows.append((f"pydy Cython peer: RK45 rtol={rtol_c:g}, {D:g} s simulated, wall [s]",
                     f"{t_cy:.2f}"))  # fmt: skip
        rows.append(("  ... its max error vs reference", f"{e_cy:.1e}"))
        rows.append(("wall per simulated second: pydy Cython peer / ours [ms]",
                     f"{per_s_cy * 1e3:.1f} / {per_s_ours * 1e3:.2f}"))  # fmt: skip
        rows.append(("speed-up (pydy Cython peer / ours per simulated second)",
                     f"{per_s_cy / per_s_ours:.0f}x"))  # fmt: skip
        peers.append(("pydy Cython peer", per_s_cy, e_cy))

    # Equal accuracy the other way round: refine our step until we are as accurate as the
    # most accurate peer.
    target = min(e for _, _, e in peers)
    for sub in (4, 8, 16, 32):
        tr_fine = simulate(bike, x0, 50.0, controller=controller, substeps=sub)
        e_fine = float(np.max(np.abs(tr_fine.y[:n] - ref.y[:n])))
        if e_fine <= target:
            break
    fine = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        simulate(bike, x0, 50.0, controller=controller, substeps=sub)
        fine.append(time.perf_counter() - t0)
    per_s_fine = statistics.median(fine) / 50.0
    rows.append((f"ours at the peers' accuracy ({sub} substeps): error, wall per simulated s [ms]",
                 f"{e_fine:.1e}, {per_s_fine * 1e3:.2f}"))  # fmt: skip
    for name, per_s, _ in peers:
        rows.append((f"speed-up at equal accuracy vs the {name}", f"{per_s / per_s_fine:.0f}x"))

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}, load avg {os.getloadavg()[0]:.1f}")  # fmt: skip
    print("| quantity | value |\n|---|---|")
    for k, v in rows:
        print(f"| {k} | {v} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
