"""Discovery's held-out goal on every speed split: discover on some speeds, evaluate on the others.

For each split, runs ``bikeid measured discover``'s pipeline on the steer-by-wire free decays of
the fit speeds (:func:`bikeid.ident.effects.discover`, nonlinear plant by default, the windows
it cannot simulate dropped as the command drops them) and evaluates the nominal and the model
with the kept terms on the decays of every other speed (the before/after of ``bikeid measured
evaluate``: :func:`bikeid.ident.effects.diagnostics.evaluate`).  One row per split: the terms
kept (equation, term, coefficient with its 95 % interval), and the held-out decay error before
-> after with the ratio's 95 % interval (paired bootstrap over the held-out decays, stratified
by file; the fit held fixed) and the sign-flip p-value.  A split is "halved" only when the whole
interval lies below 0.5 (the goal).

Default splits: the two two-speed splits and the four leave-one-speed-out splits of
``benchmarks/measured_speed_splits.py`` (the same six, so the two tables compare).

    python benchmarks/discovery_speed_splits.py --data ../shared/data
    python benchmarks/discovery_speed_splits.py --data ../shared/data --splits "2.5,4.5"
    python benchmarks/discovery_speed_splits.py --data ../shared/data --plant linear --json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

from bikeid.dataset.logs import LogOptions
from bikeid.ident.effects.diagnostics import evaluate
from bikeid.ident.effects.discovery import discover
from bikeid.ident.effects.discovery.dictionary import registered
from bikeid.ident.effects.log_decays import decays_from_logs
from bikeid.ident.effects.pipeline import simulable_windows

SPLITS = "2.5,4.5;1.5,3.5;2.5,3.5,4.5;1.5,3.5,4.5;1.5,2.5,4.5;1.5,2.5,3.5"


def _decays(data: str | None, **kw) -> tuple[list, object]:
    ws, model, _law, _report = decays_from_logs(
        [], LogOptions(format="sbw"), data=data, note=lambda _s: None, **kw
    )
    return ws, model


def run_split(data: str | None, fit_speeds: list[float], plant: str = "nonlinear") -> dict:
    """Discover on ``fit_speeds``, evaluate on every other speed: the row of the table."""
    t0, c0 = time.perf_counter(), time.process_time()
    nonlinear = plant == "nonlinear"
    fit_w, model = _decays(data, speeds=fit_speeds, purpose="the discovery")
    held, _ = _decays(data, exclude=fit_speeds, purpose="the evaluation")
    dropped = 0
    if nonlinear:
        fit_w, d1 = simulable_windows(model, fit_w)
        held, d2 = simulable_windows(model, held)
        dropped = len(d1) + len(d2)
    res = discover(model, fit_w, nonlinear=nonlinear)
    with registered(res.kept):  # the kept terms' entries, to simulate res.model
        s = evaluate(model, res.model, held, nonlinear)["summary"]
    return {
        "fit_speeds": fit_speeds,
        "heldout_speeds": sorted({round(float(w.speed), 1) for w in held}),
        "plant": plant,
        "decays_fit": len(fit_w),
        "decays_heldout": len(held),
        "dropped": dropped,
        "terms": [{k: t[k] for k in ("equation", "term", "coefficient", "interval", "unit",
                                     "reading")} for t in res.terms],  # fmt: skip
        "error_before": s["error_before"],
        "error_after": s["error_after"],
        "ratio": s["ratio"],
        "ratio_ci": s["ratio_ci"],
        "p_value": s["p_value"],
        "verdict": s["verdict"],
        "seconds": time.perf_counter() - t0,
        "cpu_seconds": time.process_time() - c0,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="data directory (default $BIKEID_DATA)")
    ap.add_argument("--splits", default=SPLITS,
                    help="fit-speed sets separated by ';' (each evaluated on the other speeds)")
    ap.add_argument("--plant", choices=("nonlinear", "linear"), default="nonlinear",
                    help="nominal plant, as for 'bikeid measured discover' (default nonlinear)")
    ap.add_argument("--json", action="store_true", help="print the rows as JSON")
    a = ap.parse_args(argv)
    if not a.json:
        print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python "
              f"{platform.python_version()}, load {os.getloadavg()[0]:.1f}")  # fmt: skip
    rows = []
    for text in a.splits.split(";"):
        sp = [float(x) for x in text.split(",") if x.strip()]
        r = run_split(a.data, sp, a.plant)
        rows.append(r)
        if not a.json:
            terms = "; ".join(
                f"{t['equation']}: {t['term']} {t['coefficient']:.3g} "
                f"({t['interval'][0]:.3g}..{t['interval'][1]:.3g}) {t['unit']}"
                for t in r["terms"]
            ) or "nothing kept"
            ratio = (f"{r['ratio']:.2f}, 95 % interval {r['ratio_ci'][0]:.2f}-"
                     f"{r['ratio_ci'][1]:.2f}, p = {r['p_value']:.2g}: {r['verdict']}")  # fmt: skip
            print(f"fit {'+'.join(map(str, r['fit_speeds']))} -> "
                  f"{'+'.join(map(str, r['heldout_speeds']))} ({r['decays_fit']} + "
                  f"{r['decays_heldout']} decays, {r['dropped']} dropped): {terms}; held-out "
                  f"error {r['error_before']:.3f} -> {r['error_after']:.3f} ({ratio}) "
                  f"[{r['cpu_seconds']:.0f} s CPU]", flush=True)  # fmt: skip
    if a.json:
        print(json.dumps(rows, indent=1))
    else:
        print(f"decay error halved (whole 95 % interval below 0.5) on "
              f"{sum(r['verdict'] == 'halved' for r in rows)} of {len(rows)} splits")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
