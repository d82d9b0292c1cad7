"""Could the pipeline halve both held-out errors on data like ours if the truth were in the library?

A parametric bootstrap of the whole pipeline on replicas of the real experiment:

1. fit a fixed set of library effects (``--truth``) jointly on the free decays of all
   speeds; that model is the "truth" of the replicas;
2. a replica keeps every real decay's initial state and speed, and replaces its signals by
   the truth's simulation from that state (nonlinear plant by defect correction) plus the
   residual (data - truth, all four channels) of a decay drawn at random, with replacement,
   from the same speed; so the replicas carry the real noise *and* the real part of the
   residual that the truth does not explain;
3. on each replica, ``bikeid measured fit`` on the fit speeds and ``bikeid measured
   evaluate`` on the others, for both two-speed splits; the "oracle" row evaluates the truth
   itself on the same held-out replica decays (the best any selection could do).

It first prints how much of the truth's residual on the real decays is the same waveform in
every push of a speed (systematic, not noise; for independent noise the fraction would be
about 1 / number of decays, 0.11-0.17 here).  Then, per split, how often both held-out ratios
(decay error, weave error) are <= 0.5, their medians, and how often the selected set equals
the truth set.

    python benchmarks/measured_replicas.py --data ../shared/data --replicas 20
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

from bikeid.dataset.decays import load_decays
from bikeid.ident.effects.experiment_model import with_nonlinear_correction
from bikeid.ident.effects.pipeline import evaluate_json, fit_effect_set, fit_model

CHANNELS = ("phi", "delta", "phidot", "deltadot")
SPLITS = ((2.5, 4.5), (1.5, 3.5))
_STATE: dict = {}


def setup(data: str | None, truth_set: list[str]) -> dict:
    """Fit the truth on all decays; keep its simulation of each decay."""
    ws = load_decays(data)
    truth = fit_effect_set(ws, truth_set).model
    ws = with_nonlinear_correction(ws, truth)
    return {"windows": ws, "truth": truth, "sims": truth.simulate(ws)}


def systematic_fractions(state: dict) -> list[tuple[float, str, float, float]]:
    """How much of the truth's residual is the same in every push, per speed and channel.

    The residual of each decay (first 1 s) is multiplied by the sign of its initial roll
    rate (mirror symmetry: a push to the left is the mirror image of one to the right) and
    the mean over the decays of a speed is taken; ``odd`` = n * ||mean||^2 / sum ||r_i||^2 is
    the fraction of residual energy in that common, push-proportional waveform (1/n for
    independent noise), ``even`` the same without the sign (a common offset-like part).
    The two overlap when the push directions are unbalanced (3.5 m/s: 7 left, 2 right).
    """
    ws, sims = state["windows"], state["sims"]
    rows = []
    for sp in sorted({round(w.speed, 1) for w in ws}):
        idx = [i for i, w in enumerate(ws) if round(w.speed, 1) == sp and w.n >= 100]
        for c in ("phidot", "delta"):
            raw = np.array([(getattr(ws[i], c) - sims[i][c])[:100] for i in idx])
            sgn = np.array([np.sign(ws[i].state0()[2]) for i in idx])[:, None]
            frac = [len(idx) * np.sum(r.mean(0) ** 2) / np.sum(r**2) for r in (raw * sgn, raw)]
            rows.append((sp, c, float(frac[0]), float(frac[1])))
    return rows


def replica(state: dict, seed: int, copies: int = 1) -> list:
    """Truth simulation of every decay + the residual of a random decay of the same speed;
    ``copies`` replica decays per real one (each with its own residual draw)."""
    ws, sims = state["windows"], state["sims"]
    rng = np.random.default_rng(seed)
    speeds = np.array([round(w.speed, 1) for w in ws])
    out = []
    for i, w in [(i, w) for _ in range(copies) for i, w in enumerate(ws)]:
        j = int(rng.choice(np.flatnonzero(speeds == speeds[i])))
        n = min(w.n, ws[j].n)
        sig = {c: sims[i][c][:n] + getattr(ws[j], c)[:n] - sims[j][c][:n] for c in CHANNELS}
        out.append(replace(w, v_sensor=w.v_sensor[:n], T_ext=w.T_ext[:n], correction=None, **sig))
    return out


def _init(data, truth_set, copies: int = 1) -> None:
    _STATE.update(setup(data, truth_set), copies=copies)


def run_one(job: tuple[int, tuple[float, float]]) -> dict:
    seed, split = job
    rep = replica(_STATE, seed, _STATE["copies"])

    def near(w):
        return any(abs(w.speed - s) < 0.25 for s in split)

    fit_w = [w for w in rep if near(w)]
    held = [w for w in rep if not near(w)]
    model = fit_model(fit_w)
    s = evaluate_json(model, held)["summary"]
    oracle = {"effects": dict(_STATE["truth"].effects), "plant": "nonlinear"}
    o = evaluate_json(oracle, held)["summary"]
    return {
        "seed": seed,
        "fit_speeds": list(split),
        "verdict": model["identification"]["verdict"],
        "effects": model["effects"],
        "ratio": s["ratio"],
        "weave_ratio": s["weave_ratio"],
        "oracle_ratio": o["ratio"],
        "oracle_weave_ratio": o["weave_ratio"],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", help="data directory (default $BIKEID_DATA)")
    ap.add_argument(
        "--truth",
        default="steer_viscous_damping,steer_stiffness,steer_angle_bias",
        help="library effects of the truth, fitted on all speeds",
    )
    ap.add_argument("--replicas", type=int, default=20)
    ap.add_argument(
        "--copies",
        type=int,
        default=1,
        help="replica decays per real decay (k > 1: what k times as many pushes would give; "
        "conservative, since the residuals are drawn from the same few real decays)",
    )
    ap.add_argument("--processes", type=int, default=2)
    ap.add_argument("--json", help="also write the rows to this file")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    truth_set = [x for x in a.truth.split(",") if x]
    if a.copies < 1 or a.replicas < 1:
        raise SystemExit("--copies and --replicas must be >= 1")
    _init(a.data, truth_set, a.copies)
    print("truth:", ", ".join(f"{k} {v:.3g}" for k, v in _STATE["truth"].effects.items()))
    print("the truth's residual on the real decays, fraction common to all pushes of a speed:")
    for sp, c, odd, even in systematic_fractions(_STATE):
        print(f"  {sp} m/s {c:7s} push-proportional {odd:.2f}, offset-like {even:.2f}")
    jobs = [(seed, sp) for seed in range(a.replicas) for sp in SPLITS]
    with ProcessPoolExecutor(
        a.processes, initializer=_init, initargs=(a.data, truth_set, a.copies)
    ) as ex:
        rows = list(ex.map(run_one, jobs))
    for sp in SPLITS:
        rr = [r for r in rows if tuple(r["fit_speeds"]) == sp]
        both = sum(r["ratio"] <= 0.5 and r["weave_ratio"] <= 0.5 for r in rr)
        oboth = sum(r["oracle_ratio"] <= 0.5 and r["oracle_weave_ratio"] <= 0.5 for r in rr)
        exact = sum(set(r["effects"]) == set(truth_set) for r in rr)
        print(
            f"fit {sp[0]}+{sp[1]}: pipeline halves both in {both}/{len(rr)} (median error ratio "
            f"{np.median([r['ratio'] for r in rr]):.2f}, weave "
            f"{np.median([r['weave_ratio'] for r in rr]):.2f}); selects the truth set in "
            f"{exact}/{len(rr)}; the truth itself halves both in {oboth}/{len(rr)} (median "
            f"{np.median([r['oracle_ratio'] for r in rr]):.2f}, weave "
            f"{np.median([r['oracle_weave_ratio'] for r in rr]):.2f})"
        )
    print(
        f"{len(rows)} pipeline runs ({a.copies} replica decays per real one) in "
        f"{time.perf_counter() - t0:.0f} s"
    )
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
