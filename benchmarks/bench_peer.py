"""Peer comparison: the same closed-loop files identified by bikeid and by independent Python
subspace codes; eigenvalue errors against the truth and time per fit, side by side.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_peer.py [--speeds 2,4,5,6,8]
        [--repeats 3] [--block-rows 40] [--json peer.json]

Data: the accuracy study's closed-loop runs (``bikeid.experiments.testbed.accuracy.generate``:
nonlinear Whipple plant, roll PID, 3 deg roll chirp reference + 1 N m steer-torque dither
held per speed band, default sensors (1e-3 rad, 1e-2 rad/s), 100 Hz, 50 s, seed 0),
written to HDF5 in a temporary folder and read back; every method gets these same runs.

Methods (model order 4 for all):

- bikeid PEM: ``ident.pem.fit`` on one speed's run (canonical model, free Kalman gain,
  PBSID multistart), outputs phi, delta, phidot, deltadot.
- bikeid direct: Moore & Hubbard's equations of motion by instrumental variables
  (``experiments.testbed.accuracy.identify_controller(..., methods=("direct",))``, the accuracy
  study's settings: 3 Hz cut-off, dither/reference instruments at lags 0..40); one fit over
  all speeds, so its time is that one fit.
- bikeid PBSID: ``ident.subspace.pbsid`` (the PEM's closed-loop-safe subspace start),
  outputs phi, delta, VARX past window 50 samples.
- nfoursid ``NFourSID`` (PO-MOESP instruments with an N4SID state step): input T_delta,
  outputs phi, delta (and a second row with the rates phidot, deltadot as well),
  ``num_block_rows`` = ``--block-rows``, ``system_identification(rank=4)``.
- sippy-unipi ``system_identification``: ``"N4SID"`` (open-loop) and ``"PARSIM-K"``
  (Pannocchia's closed-loop variant), input T_delta, outputs phi, delta,
  ``SS_f`` = ``SS_p`` = ``--block-rows``, ``SS_fixed_order=4``.

The discrete models' eigenvalues are mapped to continuous time by log(z)/dt.  Errors:
``experiments.testbed.accuracy.eigen_errors`` (identified eigenvalues paired with the true weave
pair,
capsize and caster by ``sim.linear.match_eigenvalues``) against the true linearization
(``experiments.testbed.accuracy.true_modes``); "within tolerance" uses the accuracy study's
max(0.02 |lambda|, 0.05 1/s).  Times: per speed the median of ``--repeats`` fits, then the
median over speeds.  The peers are optional (``pip install .[bench]``); a missing one is
listed as not installed.  Timings depend on the machine and its load; quote the machine
(docs/performance.md).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import importlib.metadata  # noqa: E402
import io  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import numpy as np  # noqa: E402

from bikeid.dataset.files import atomic_write_text  # noqa: E402
from bikeid.dataset.store import read_runs  # noqa: E402
from bikeid.experiments import accuracy as acc  # noqa: E402
from bikeid.experiments.cli.args import dump_json, parse_range  # noqa: E402
from bikeid.ident import pem  # noqa: E402
from bikeid.ident.subspace import pbsid  # noqa: E402
from bikeid.sim.parameters import benchmark  # noqa: E402

MODES = ("weave", "capsize")


def _version(dist: str) -> str | None:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return None


def _discrete_eigs(A: np.ndarray, dt: float) -> np.ndarray:
    """Continuous-time eigenvalues [1/s] of a discrete state matrix: log(z) / dt."""
    return np.log(np.linalg.eigvals(A).astype(complex)) / dt


def _signals(run, names) -> np.ndarray:
    return np.column_stack([np.asarray(run[n], float) for n in names])


def method_pem(run) -> np.ndarray:
    return pem.fit(run).eigenvalues()


def method_pbsid(run) -> np.ndarray:
    A, *_ = pbsid(_signals(run, ["T_delta"]), _signals(run, ["phi", "delta"]), n=4, p=50)
    return _discrete_eigs(A, run.dt)


def nfoursid_method(rows: int, outputs: list[str]) -> Callable:
    import pandas as pd
    from nfoursid.nfoursid import NFourSID

    def fit(run) -> np.ndarray:
        frame = pd.DataFrame({n: np.asarray(run[n], float) for n in ["T_delta", *outputs]})
        n4 = NFourSID(frame, output_columns=outputs, input_columns=["T_delta"],
                      num_block_rows=rows)  # fmt: skip
        n4.subspace_identification()
        ss, _ = n4.system_identification(rank=4)
        return _discrete_eigs(ss.a, run.dt)

    return fit


def sippy_method(name: str, rows: int) -> Callable:
    from sippy_unipi import system_identification

    def fit(run) -> np.ndarray:
        y, u = _signals(run, ["phi", "delta"]).T, _signals(run, ["T_delta"]).T
        with contextlib.redirect_stdout(io.StringIO()):  # it prints its progress
            model = system_identification(y, u, name, SS_fixed_order=4, SS_f=rows, SS_p=rows,
                                          tsample=run.dt)  # fmt: skip
        return _discrete_eigs(model.A, run.dt)

    return fit


def _timed(f: Callable, repeats: int):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t0)
    return out, statistics.median(times)


def per_speed(name: str, settings: str, fit: Callable, runs, truth, repeats: int) -> dict:
    """Identify each run with ``fit``; per speed the mode errors and the median time."""
    rows = []
    for r in runs:
        v = round(r.speed, 6)
        try:
            eig, t = _timed(lambda r=r: fit(r), repeats)
        except Exception as exc:  # noqa: BLE001 - a peer's failure is a result to report
            rows.append({"speed": v, "error": f"{type(exc).__name__}: {exc}"[:200]})
            continue
        rows.append({"speed": v, "seconds": t, "eigenvalues": eig,
                     "modes": acc.eigen_errors(eig, truth[v])})  # fmt: skip
    return {"method": name, "settings": settings, "rows": rows}


def direct_all_speeds(runs, p, repeats: int) -> dict:
    """The direct method: one instrumental-variable fit over all speeds."""
    res, t = _timed(lambda: acc.identify_controller(runs, p, ("direct",)), repeats)
    rows = [{"speed": row["speed"], "seconds": None, "modes": row["modes"]}
            for row in res["methods"]["direct"]["rows"]]  # fmt: skip
    return {
        "method": "bikeid direct",
        "seconds_all_speeds": t,
        "rows": rows,
        "settings": "IV, dither + reference lags 0..40, 3 Hz cut-off, all speeds in one fit",
    }


def summarize(result: dict) -> dict:
    ok = [r for r in result["rows"] if "modes" in r]
    out = {"speeds": len(result["rows"]), "failed": len(result["rows"]) - len(ok)}
    for m in MODES:
        errs = [r["modes"][m]["error"] for r in ok if m in r["modes"]]
        out[f"{m}_median"] = statistics.median(errs) if errs else None
        out[f"{m}_max"] = max(errs) if errs else None
        out[f"{m}_within"] = sum(r["modes"][m]["pass"] for r in ok if m in r["modes"])
    times = [r["seconds"] for r in ok if r.get("seconds") is not None]
    out["seconds_per_fit"] = statistics.median(times) if times else result.get("seconds_all_speeds")
    return out


def table(results: list[dict]) -> str:
    head = (f"{'method':30s} {'weave err [1/s]':>17s} {'capsize err [1/s]':>17s} "
            f"{'within tol':>11s} {'s/fit':>7s}")  # fmt: skip
    lines = [head, f"{'':30s} {'median':>8s} {'max':>8s} {'median':>8s} {'max':>8s} "
             f"{'w/c':>11s}"]  # fmt: skip
    for res in results:
        s = res.get("summary")
        if s is None:
            lines.append(f"{res['method']:30s} {res['note']}")
            continue

        def f(x):
            return f"{x:8.3f}" if x is not None else f"{'-':>8s}"

        within = f"{s['weave_within']}/{s['capsize_within']} of {s['speeds']}"
        secs = "-" if s["seconds_per_fit"] is None else f"{s['seconds_per_fit']:7.3f}"
        lines.append(f"{res['method']:30s} {f(s['weave_median'])} {f(s['weave_max'])} "
                     f"{f(s['capsize_median'])} {f(s['capsize_max'])} {within:>11s} {secs:>7s}"
                     + (f"  ({s['failed']} failed)" if s["failed"] else ""))  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speeds", default="2,4,5,6,8", help="speeds [m/s] (default 2,4,5,6,8)")
    ap.add_argument("--repeats", type=int, default=3, help="fits per method and speed")
    ap.add_argument(
        "--block-rows",
        type=int,
        default=40,
        help="nfoursid num_block_rows and sippy SS_f = SS_p (default 40)",
    )
    ap.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = ap.parse_args()
    if args.repeats < 1 or args.block_rows < 2:
        ap.error("--repeats must be >= 1 and --block-rows >= 2")
    speeds = [float(v) for v in parse_range(args.speeds, "--speeds", minimum=0.5)]
    p = benchmark()
    machine = (f"{platform.machine()}, {os.cpu_count()} cores, python "
               f"{platform.python_version()}, numpy {np.__version__}, load average "
               f"{os.getloadavg()[0]:.1f}")  # fmt: skip
    print(f"machine: {machine}")
    with tempfile.TemporaryDirectory(prefix="bench_peer_") as tmp:
        generated = acc.generate(tmp, "pid", speeds, workers=1)
        files = sorted(os.path.join(tmp, "data", f) for f in os.listdir(os.path.join(tmp, "data"))
                       if f.endswith(".h5"))  # fmt: skip
        runs = sorted((r for f in files for r in read_runs(f)), key=lambda r: r.speed)
    assert len(runs) == len(generated), "the files hold the generated runs"
    truth = acc.true_modes(p, [r.speed for r in runs])
    rows = args.block_rows
    results = [
        per_speed(
            "bikeid PEM",
            "canonical PEM, 4 outputs, PBSID multistart",
            method_pem,
            runs,
            truth,
            args.repeats,
        ),  # fmt: skip
        direct_all_speeds(runs, p, args.repeats),
        per_speed(
            "bikeid PBSID",
            "outputs phi, delta; VARX past 50 samples",
            method_pbsid,
            runs,
            truth,
            args.repeats,
        ),  # fmt: skip
    ]
    peers = {"nfoursid": _version("nfoursid"), "sippy-unipi": _version("sippy-unipi")}
    if peers["nfoursid"]:
        for outs, tag in ((["phi", "delta"], "phi, delta"),
                          (["phi", "delta", "phidot", "deltadot"], "+ rates")):  # fmt: skip
            results.append(per_speed(
                f"nfoursid ({tag})", f"num_block_rows={rows}, rank 4, outputs {outs}",
                nfoursid_method(rows, outs), runs, truth, args.repeats))  # fmt: skip
    else:
        results.append({"method": "nfoursid", "note": "not installed (pip install .[bench])"})
    if peers["sippy-unipi"]:
        for name in ("N4SID", "PARSIM-K"):
            results.append(per_speed(
                f"sippy {name} (phi, delta)", f"SS_f=SS_p={rows}, SS_fixed_order=4",
                sippy_method(name, rows), runs, truth, args.repeats))  # fmt: skip
    else:
        results.append({"method": "sippy-unipi", "note": "not installed (pip install .[bench])"})
    for res in results:
        if "rows" in res:
            res["summary"] = summarize(res)
    print(f"speeds {speeds} m/s; {args.repeats} repeats; block rows {rows}; peers {peers}")
    print(table(results))
    if args.json:
        atomic_write_text(args.json, dump_json({
            "machine": machine, "speeds": speeds, "repeats": args.repeats, "block_rows": rows,
            "peers": peers, "results": results}) + "\n")  # fmt: skip
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
