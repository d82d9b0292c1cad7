"""Rates of ``ident.effects.discover`` on the project's own generator, with injected terms.

Each seed draws decays of the linear experiment model (``synthetic_decays``: 2 speeds x 4
decays by default, 1 s, 0.005 rad/s roll-rate noise and the steer encoder's quantization)
with one dictionary term injected through an effects file (``discovery.injection_file``: the
effect-law mechanism, not a special case), and runs the discovery (linear plant, default
rule: family-wise 0.05, Bonferroni over 43 terms x 3 rounds).  Per injected term it reports,
with exact (Clopper-Pearson) 95 % intervals, how often:

- ``found``: the term is kept, or is in the kept term's indistinguishable set, with nothing
  extra (exactly one term kept);
- ``direct``: the term itself is kept (nothing extra);
- ``within35``: its coefficient (kept, or as a member of the set) is within 35 % of the truth;
- ``covers``: its 95 % interval covers the truth;

and, for ``--no-effect`` seeds, how often anything is kept (false discoveries).

Usage::

    python benchmarks/bench_discovery.py [--terms "roll: phidot=-3" ...] [--seeds 10]
        [--first-seed 100] [--no-effect 20] [--json rates.json]

Seeds used while building (development data): 0-9 for ``roll: phidot=-3``, 0-19 with no
term.  Quote rates from other seeds.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from bikeid.experiments.measured.discovery_scores import score_discovery
from bikeid.experiments.measured.effect_trials import rate
from bikeid.ident.effects.acceptance import AcceptanceRule
from bikeid.ident.effects.discovery import discover, injection_file
from bikeid.ident.effects.experiment_model import ExperimentModel
from bikeid.ident.effects.synthetic_decays import synthetic_windows
from bikeid.sim.effect_files import load_effects_file
from bikeid.sim.effect_registry import unregister_effects

DEFAULT_TERMS = ("roll: phidot=-3",)
KEYS = ("found", "direct", "within35", "covers")


def _decays(term: str | None, coef: float, seed: int, speeds, per_speed: int, noise: float):
    """Decays of the experiment model with ``term`` injected through an effects file (None:
    none); the file's entry stays registered while the generator simulates it."""
    if not term:
        return synthetic_windows(ExperimentModel(), speeds, per_speed, noise=noise, seed=seed)
    with tempfile.TemporaryDirectory() as tmp:
        f = load_effects_file(injection_file(Path(tmp) / "inject.yaml", {term: coef}))
    try:
        truth = ExperimentModel(effects=dict(f.values))
        return synthetic_windows(truth, speeds, per_speed, noise=noise, seed=seed)
    finally:
        unregister_effects(f.names)


def one(term: str | None, coef: float, seed: int, speeds, per_speed: int, noise: float) -> dict:
    """One seed: the discovery on decays with ``term`` (None: no term) injected."""
    ws = _decays(term, coef, seed, speeds, per_speed, noise)
    t0 = time.process_time()
    # the project's generator simulates the stated bicycle: the search alone, taken as exact
    d = discover(ExperimentModel(), ws, rule=AcceptanceRule.exact())
    row = {"term": term, "coefficient": coef, "seed": seed, "cpu_s": time.process_time() - t0}
    row.update(score_discovery(d.terms, term, coef))
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--terms", nargs="+", default=list(DEFAULT_TERMS),
                    help='injected terms "equation: term=coefficient" (SI)')  # fmt: skip
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--no-effect", type=int, default=20, help="no-effect seeds")
    ap.add_argument("--speeds", default="2.0,3.5")
    ap.add_argument("--per-speed", type=int, default=4)
    ap.add_argument("--noise", type=float, default=0.005)
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    speeds = [float(x) for x in a.speeds.split(",")]
    seeds = range(a.first_seed, a.first_seed + a.seeds)
    rows, summary = [], {}
    for spec in a.terms:
        term, _, c = spec.rpartition("=")
        part = [one(term.strip(), float(c), s, speeds, a.per_speed, a.noise) for s in seeds]
        for r in part:
            print(json.dumps(r), flush=True)
        rows += part
        summary[spec] = {k: rate(part, k) for k in KEYS}
    quiet = [one(None, 0.0, s, speeds, a.per_speed, a.noise)
             for s in range(a.first_seed, a.first_seed + a.no_effect)]  # fmt: skip
    rows += quiet
    summary["no effect"] = {"false_discovery": rate(quiet, "false_discovery")}
    cpu = [r["cpu_s"] for r in rows]
    summary["cpu_s_per_run"] = {"mean": sum(cpu) / len(cpu), "max": max(cpu)}
    for k, v in summary.items():
        print(k, json.dumps(v))
    if a.json:
        Path(a.json).write_text(json.dumps({"rows": rows, "summary": summary}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
