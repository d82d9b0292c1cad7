"""Rates of ``bikeid measured discover`` on the independent generator, by term and log format.

Per injected term (``--terms``), ``--seeds`` trials of the blind generator
(``experiments.measured.blind_trials``: Moore's canonical matrices from bicycleparameters
with every inertia and the trail perturbed within their uncertainty, coloured gyro noise,
bias and drift, an encoder, treadmill speed wander, the 100 Hz steer-into-lean loop, roll
pushes) carry the term with its coefficient (``with_terms``: the generalized torque
``coefficient * term`` added to its equation, positive adding torque, the discovery's own
convention).  Each trial's two fit speeds are written as CSV logs of another lab's format
(ms, degrees, km/h, roll positive left; ``write_trial_logs``, 8 pushes per log), and
``bikeid measured discover FILES ... --json`` reads them in two formats:

- ``torque``: the logged torque only (no controller law: the k-step error), a stranger's logs;
- ``law``: with the loop law given (``--controller steer-into-lean --gains K=2,V=6.5``).

Per term and format, with exact (Clopper-Pearson) 95 % intervals
(``experiments.measured.effect_trials.rate``; scores of
``experiments.measured.discovery_scores``): ``found`` (the injected equation and term kept,
or in the kept term's indistinguishable set, with nothing extra), ``direct`` (the term
itself), ``within35`` (its coefficient within 35 % of the truth), ``covers`` (its 95 %
interval covers it); on ``--no-effect`` trials, how often anything is kept.  With
``--agreement`` the ``steer: deltadot`` trials (the library's steer viscous damping, which
the grammar expresses) are also fitted by ``bikeid measured fit`` in the same format and
plant, and the benchmark counts how often the fit's selection (steer_viscous_damping named
alone, or in the named effect's ambiguity set) agrees with the discovery's ``found``.

Usage::

    nice python benchmarks/bench_discovery_rates.py [--terms "roll: phidot=-5" ...]
        [--seeds 5] [--first-seed 300] [--no-effect 10] [--formats torque,law]
        [--plant linear|nonlinear] [--exact-bicycle] [--nominal-uncertainty U]
        [--agreement] [--processes 1]
        [--json rates.json]

Trial ``i`` of seed ``s`` is ``draw_term_trials(1, s, ..., first=i)`` with ``i`` the term's
position in ``--terms`` (no-effect trials: ``i = len(terms)``), so every kind draws its own
nuisances.  ``--plant`` is discover's nominal plant (default ``linear``, the truth's; the
command's default, ``nonlinear``, cost 5.6x more CPU on the torque-only logs of a building
seed).
``--exact-bicycle`` removes the inertia and trail perturbation (a diagnostic: the stated
bicycle is then the truth's).  Progress lines go to stderr, one JSON row per trial and
format to stdout, the summary last.

Seeds used while building (development data, not to be quoted): 0 and 1.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from bikeid.experiments.measured.blind_trials import (
    BODY_INERTIAS,
    draw_term_trials,
    log_import_options,
    write_trial_logs,
)
from bikeid.experiments.measured.discovery_scores import score_discovery
from bikeid.experiments.measured.effect_trials import rate
from bikeid.experiments.parallel import imap

DEFAULT_TERMS = ("roll: phidot=-5", "roll: phi=-30", "steer: deltadot=-0.4",
                 "steer: delta=-0.6", "steer: v*deltadot=-0.15")  # fmt: skip
FORMATS = ("torque", "law")
KEYS = ("found", "direct", "within35", "covers")
#: The library effect whose law is ``steer: deltadot`` (compared with ``measured fit``).
AGREE_TERM, AGREE_EFFECT = "steer: deltadot", "steer_viscous_damping"


def _cli(args: list[str]) -> tuple[int, str, str]:
    """``bikeid ARGS`` in this process: exit status, stdout, last stderr line."""
    from bikeid.experiments.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(args)
    last = err.getvalue().strip().splitlines()[-1:] or [""]
    return rc, out.getvalue(), last[0]


def _options(fmt: str) -> list[str]:
    """The CSV import options of a format (``torque``: without the controller law)."""
    opts = log_import_options()
    return opts[: opts.index("--controller")] if fmt == "torque" else opts


def _fit_agrees(files, fmt: str, plant: str, folder: Path) -> dict:
    """``measured fit`` on the same logs: is the steer viscous damping its selection?"""
    out = folder / f"fit_{fmt}.json"
    rc, _, err = _cli(["measured", "fit", *map(str, files), *_options(fmt), "--plant", plant,
                       "--out", str(out), "--quiet"])  # fmt: skip
    if rc != 0:
        return {"fit_rc": rc, "fit_error": err, "fit_selects": False, "fit_verdict": None}
    ident = json.loads(out.read_text())["results"]["identification"]
    names = [n for n in ident["verdict"] if n != "unexplained"]
    own = ident.get("ambiguity", {}).get(names[0], []) if names else []
    selects = len(names) == 1 and (names[0] == AGREE_EFFECT or AGREE_EFFECT in own)
    return {"fit_rc": 0, "fit_verdict": ident["verdict"], "fit_selects": selects}


def _job(args: tuple) -> list[dict]:
    """One trial: write its logs, discover in every format (and fit, for the agreement)."""
    trial, term, coef, grid_seed, formats, plant, agreement, uncertainty = args
    rows = []
    t0 = time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        try:
            files = write_trial_logs(trial, folder, "independent_linear")
        except RuntimeError as exc:  # the plant fell with every push scale
            return [{"term": term, "coefficient": coef, "index": trial.index,
                     "seed": grid_seed, "format": f, "rc": None, "error": str(exc),
                     **score_discovery([], term, coef)} for f in formats]  # fmt: skip
        gen = time.process_time() - t0
        for fmt in formats:
            t1 = time.process_time()
            rc, out, err = _cli(["measured", "discover", *map(str, files), *_options(fmt),
                                 "--plant", plant, "--nominal-uncertainty", uncertainty,
                                 "--json"])  # fmt: skip
            row = {"term": term, "coefficient": coef, "index": trial.index, "seed": grid_seed,
                   "format": fmt, "fit_speeds": list(trial.fit_speeds),
                   "noise": trial.nuisance.noise, "rc": rc, "error": None if rc == 0 else err,
                   "generate_cpu_s": gen}  # fmt: skip
            res = json.loads(out) if rc == 0 else {"terms": []}
            row.update(score_discovery(res["terms"], term, coef))
            row["decays"] = res.get("decays")
            row["ratio"] = (res.get("before_after") or {}).get("ratio")
            row["terms"] = [{k: d[k] for k in ("equation", "term", "coefficient", "interval")}
                            for d in res["terms"]]  # fmt: skip
            row["cpu_s"] = time.process_time() - t1
            if agreement and term == AGREE_TERM and rc == 0:
                t2 = time.process_time()
                row.update(_fit_agrees(files, fmt, plant, folder))
                row["agree"] = row["fit_selects"] == row["found"]
                row["fit_cpu_s"] = time.process_time() - t2
            rows.append(row)
    return rows


def _trials(spec: list[tuple[str | None, float]], seeds, no_effect_seeds, exact: bool):
    """(trial, term, coefficient, grid seed) for every term and seed, then the no-effect
    trials."""
    out = []
    for i, (term, coef) in enumerate(spec):
        for s in seeds:
            out.append((draw_term_trials(1, s, {term: coef}, first=i)[0], term, coef, s))
    for s in no_effect_seeds:
        out.append((draw_term_trials(1, s, {}, first=len(spec))[0], None, 0.0, s))
    if exact:
        one = {b: 1.0 for b in BODY_INERTIAS}
        out = [(replace(t, nuisance=replace(t.nuisance, inertia_scale=one, trail_shift=0.0)),
                term, c, s) for t, term, c, s in out]  # fmt: skip
    return out


def summarize(rows: list[dict], spec, formats) -> dict:
    """Per term and format the four rates (and the agreement); per format the false
    discoveries of the no-effect trials; CPU per discovery."""
    out: dict = {}
    for term in [t for t, _ in spec] + [None]:
        for fmt in formats:
            rs = [r for r in rows if r["term"] == term and r["format"] == fmt]
            if not rs:
                continue
            key = f"{term or 'none'} [{fmt}]"
            if term is None:
                out[key] = {"false_discovery": rate(rs, "false_discovery")}
            else:
                out[key] = {k: rate(rs, k) for k in KEYS}
                if any("agree" in r for r in rs):
                    out[key]["fit_selects"] = rate([r for r in rs if "agree" in r], "fit_selects")
                    out[key]["agree"] = rate([r for r in rs if "agree" in r], "agree")
            cpu = [r["cpu_s"] for r in rs if r.get("cpu_s") is not None]
            out[key]["cpu_s"] = {"mean": sum(cpu) / len(cpu), "max": max(cpu)} if cpu else None
            out[key]["failed"] = sum(1 for r in rs if r.get("rc") != 0)
    gen = [r["generate_cpu_s"] for r in rows if r.get("generate_cpu_s") is not None]
    out["generate_cpu_s_per_trial"] = sum(gen) / len(gen) if gen else None
    return out


def _parse_terms(items: list[str]) -> list[tuple[str, float]]:
    out = []
    for spec in items:
        term, sep, c = spec.rpartition("=")
        if not sep or not term.strip():
            raise SystemExit(f"--terms: {spec!r} is not 'equation: term=coefficient'")
        out.append((term.strip(), float(c)))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--terms", nargs="+", default=list(DEFAULT_TERMS),
                    help='injected terms "equation: term=coefficient" (SI)')  # fmt: skip
    ap.add_argument("--seeds", type=int, default=5, help="trials per term")
    ap.add_argument("--first-seed", type=int, default=300)
    ap.add_argument("--no-effect", type=int, default=10, help="no-effect trials")
    ap.add_argument(
        "--formats",
        default=",".join(FORMATS),
        help="comma-separated: torque (no law, k-step), law (loop law given)",
    )
    ap.add_argument(
        "--plant",
        choices=("linear", "nonlinear"),
        default="linear",
        help="discover's nominal plant (default linear, the truth's)",
    )
    ap.add_argument(
        "--exact-bicycle", action="store_true", help="no inertia/trail perturbation (diagnostic)"
    )
    ap.add_argument(
        "--nominal-uncertainty", default="default", metavar="U",
        help="discover's --nominal-uncertainty (default 'default'; 'none': the stated "
        "bicycle taken as exact, the behaviour before the calibration)",
    )  # fmt: skip
    ap.add_argument(
        "--agreement",
        action="store_true",
        help=f"also fit the '{AGREE_TERM}' trials with measured fit",
    )
    ap.add_argument("--processes", type=int, default=1)
    ap.add_argument("--json", help="write rows and summary to this file")
    a = ap.parse_args(argv)
    spec = _parse_terms(a.terms)
    formats = tuple(f.strip() for f in a.formats.split(",") if f.strip())
    if not formats or any(f not in FORMATS for f in formats):
        raise SystemExit(f"--formats: give some of {', '.join(FORMATS)}")
    seeds = range(a.first_seed, a.first_seed + a.seeds)
    quiet = range(a.first_seed, a.first_seed + a.no_effect)
    jobs = [(t, term, c, s, formats, a.plant, a.agreement, a.nominal_uncertainty)
            for t, term, c, s in _trials(spec, seeds, quiet, a.exact_bicycle)]  # fmt: skip
    rows: list[dict] = []
    t0 = time.perf_counter()
    for n, (_, part) in enumerate(imap(_job, jobs, a.processes, None, ordered=True), 1):
        for r in part:
            rows.append(r)
            print(json.dumps(r), flush=True)
            est = "" if r.get("estimate") is None else f" estimate {r['estimate']:.4g}"
            verdict = (f"found {r['found']}{est}" if r["term"] else
                       f"false discovery {r.get('false_discovery')}")  # fmt: skip
            print(
                f"[{n}/{len(jobs)} {time.perf_counter() - t0:.0f} s] {r['term'] or 'none'}"
                f"={r['coefficient']:g} seed {r['seed']} {r['format']}: kept {r.get('kept')}"
                f"; {verdict}; cpu {r.get('cpu_s', 0):.1f} s",
                file=sys.stderr,
                flush=True,
            )
    summary = summarize(rows, spec, formats)
    for k, v in summary.items():
        print(k, json.dumps(v))
    if a.json:
        Path(a.json).write_text(json.dumps({"args": vars(a), "rows": rows, "summary": summary},
                                           indent=1, default=float))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
