"""Screening stages for the discovery: sparse regressions on the equation error against
forward selection on the closure error alone.

A screen ranks the 43 dictionary terms by a regression of the nominal model's roll- and
steer-row equation errors (``diagnostics.equation_error``: accelerations from filtered
differences of the measured rates) on the terms' signals, and passes its ``--keep`` best
terms to ``ident.effects.discover``, which fits them on the closure error and charges its
Bonferroni test with the whole dictionary's 126 tests (``family``: the screen chose the terms
on the same decays).  Screens:

- ``none``: no screen, the forward selection on the closure error tries every term;
- ``frols``: sysidentpy's FROLS error-reduction ratio (``FROLS.error_reduction_ratio``);
- ``stlsq``: pysindy's STLSQ, terms ranked by how often an ensemble of 20 bagged fits keeps
  them (stability selection, ``EnsembleOptimizer``), ties by |coefficient|;
- ``sr3``: pysindy's SR3 (L1), ranked by |coefficient| on standardized columns.

Per screen and injected term: ``screened`` (the term among the kept terms passed on),
``found`` (``discover`` keeps it, or a term whose indistinguishable set holds it, and nothing
else), false discoveries on no-effect seeds, and the CPU of screen + discovery.  Decays: the
project's generator (``synthetic_decays``, 2 speeds x 4 decays, 0.005 rad/s noise), the
term injected through an effects file.  pysindy and sysidentpy are not dependencies of
bikeid: give their location with ``PYTHONPATH``.

Usage::

    PYTHONPATH=SITE python benchmarks/bench_discovery_screening.py [--seeds 4]
        [--first-seed 200] [--no-effect 4] [--keep 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from bikeid.ident.effects.acceptance import AcceptanceRule
from bikeid.ident.effects.diagnostics import _deriv, equation_error
from bikeid.ident.effects.discovery import dictionary, discover
from bikeid.ident.effects.discovery.dictionary import registered
from bikeid.ident.effects.experiment_model import COULOMB_EPS, ExperimentModel

TERMS = ("roll: phidot=-3", "roll: phi=-30", "steer: v*deltadot=-0.1")
SCREENS = ("none", "frols", "stlsq", "sr3")


def columns(model: ExperimentModel, windows, terms) -> tuple[dict, dict]:
    """Each equation's row error and the terms' signals over the decays (the regression)."""
    ee = equation_error(model, windows)
    sig = {k: [] for k in ("phi", "delta", "phidot", "deltadot", "phiddot", "deltaddot")}
    for w in windows:
        for k in ("phi", "delta", "phidot", "deltadot"):
            sig[k].append(getattr(w, k))
        sig["phiddot"].append(_deriv(w.phidot, float(w.meta.get("dt", 0.01))))
        sig["deltaddot"].append(_deriv(w.deltadot, float(w.meta.get("dt", 0.01))))
    s = {k: np.concatenate(v) for k, v in sig.items()}
    s["1"] = np.ones_like(s["phi"])
    s["T"] = ee["T"]
    s["sign(phidot)"] = np.tanh(s["phidot"] / COULOMB_EPS)
    s["sign(deltadot)"] = np.tanh(s["deltadot"] / COULOMB_EPS)
    cols = {t.label: s[t.law.signal] * ee["v"] ** t.law.speed_power for t in terms}
    return {"roll": ee["roll"], "steer": ee["steer"]}, cols


def screen(method: str, rows: dict, cols: dict, terms, keep: int, seed: int) -> list:
    """The ``keep`` best terms by the screen's score (pooled over both equations)."""
    scores = {}
    for eq, y in rows.items():
        mine = [t for t in terms if t.equation == eq]
        X = np.column_stack([cols[t.label] for t in mine])
        X = (X - X.mean(axis=0)) / np.maximum(X.std(axis=0), 1e-12)
        X[:, [t.term == "1" for t in mine]] = 1.0
        yn = (y - y.mean()) / max(y.std(), 1e-12)
        if method == "frols":
            from sysidentpy.model_structure_selection import FROLS

            fr = FROLS(order_selection=False, n_terms=len(mine))
            fr.max_lag = 0  # a static regression: no lagged samples to drop
            err, piv, _ = fr.error_reduction_ratio(X, yn.reshape(-1, 1), len(mine))
            s = dict(zip([mine[i] for i in piv], err, strict=True))
        elif method == "stlsq":
            import pysindy as ps

            ens = ps.EnsembleOptimizer(ps.STLSQ(threshold=0.05), bagging=True, n_models=20)
            np.random.seed(seed)  # noqa: NPY002 (pysindy's bagging draws from the global one)
            ens.fit(X, yn)
            c = np.array(ens.coef_list).reshape(20, -1)
            s = {t: float(np.mean(c[:, i] != 0) + 1e-3 * abs(np.mean(c[:, i])))
                 for i, t in enumerate(mine)}  # fmt: skip
        elif method == "sr3":
            import pysindy as ps

            opt = ps.SR3(reg_weight_lam=0.01, regularizer="L1")
            opt.fit(X, yn)
            s = {t: float(abs(c)) for t, c in zip(mine, np.ravel(opt.coef_), strict=True)}
        else:
            raise ValueError(method)
        scores.update({t.label: float(v) for t, v in s.items()})
    best = sorted(scores, key=lambda k: -scores[k])[:keep]
    return [t for t in terms if t.label in best]


def run(term: str | None, coef: float, seed: int, keep: int) -> list[dict]:
    from bikeid.ident.effects.discovery import injection_file
    from bikeid.ident.effects.synthetic_decays import synthetic_windows
    from bikeid.sim.effect_files import load_effects_file
    from bikeid.sim.effect_registry import unregister_effects

    ws = synthetic_windows(ExperimentModel(), [2.0, 3.5], 4, noise=0.005, seed=seed)
    if term:  # the file's entry registered while the generator simulates it
        with tempfile.TemporaryDirectory() as tmp:
            f = load_effects_file(injection_file(Path(tmp) / "i.yaml", {term: coef}))
        try:
            truth = ExperimentModel(effects=dict(f.values))
            ws = synthetic_windows(truth, [2.0, 3.5], 4, noise=0.005, seed=seed)
        finally:
            unregister_effects(f.names)
    model = ExperimentModel()
    out = []
    with registered(dictionary()) as terms:
        for method in SCREENS:
            t0 = time.process_time()
            if method == "none":
                chosen, fam = terms, None
            else:
                rows, cols = columns(model, ws, terms)
                chosen = screen(method, rows, cols, terms, keep, seed)
                fam = sum(len(terms) - r for r in range(3))
            # the generator simulates the stated bicycle: the screens compared, taken as exact
            d = discover(model, ws, terms=chosen, family=fam, rule=AcceptanceRule.exact())
            cpu = time.process_time() - t0
            labels = [f"{x['equation']}: {x['term']}" for x in d.terms]
            alike = {f"{y['equation']}: {y['term']}" for x in d.terms
                     for y in x["indistinguishable"]}  # fmt: skip
            hit = term is not None and (term in labels or term in alike)
            out.append({"screen": method, "term": term, "seed": seed, "kept": labels,
                        "passed_on": [t.label for t in chosen] if method != "none" else [],
                        "screened": term is None or any(t.label == term for t in chosen),
                        "found": hit and len(labels) == 1,
                        "false_discovery": term is None and bool(labels),
                        "cpu_s": cpu})  # fmt: skip
    return out


def main(argv=None) -> int:
    from bikeid.experiments.measured.effect_trials import rate

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--terms", nargs="+", default=list(TERMS))
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--first-seed", type=int, default=200)
    ap.add_argument("--no-effect", type=int, default=4)
    ap.add_argument("--keep", type=int, default=3)
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    rows = []
    seeds = range(a.first_seed, a.first_seed + a.seeds)
    for spec in a.terms:
        term, _, c = spec.rpartition("=")
        for s in seeds:
            for r in run(term.strip(), float(c), s, a.keep):
                print(json.dumps(r), flush=True)
                rows.append(r)
    for s in range(a.first_seed, a.first_seed + a.no_effect):
        for r in run(None, 0.0, s, a.keep):
            print(json.dumps(r), flush=True)
            rows.append(r)
    summary = {}
    for m in SCREENS:
        mine = [r for r in rows if r["screen"] == m]
        hit = [r for r in mine if r["term"] is not None]
        summary[m] = {"screened": rate(hit, "screened"), "found": rate(hit, "found"),
                      "false_discovery": rate([r for r in mine if r["term"] is None],
                                              "false_discovery"),
                      "cpu_s_mean": float(np.mean([r["cpu_s"] for r in mine]))}  # fmt: skip
        print(m, json.dumps(summary[m]))
    if a.json:
        Path(a.json).write_text(json.dumps({"rows": rows, "summary": summary}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
