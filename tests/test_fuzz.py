"""Hostile input, generated: no traceback, a documented exit status, no collateral damage.

Three generators (hypothesis, bounded, in CI):

1. **Command lines** for every subcommand, discovered from the parser itself (a new command
   is covered the day it is registered; a mode that reads other inputs, ``measured evaluate
   --drive=logged``, is fuzzed as a command of its own): each case sets one typed option to
   a value that option's own parser refuses, plus up to four more options with hostile
   values (empty, ``--``, NaN, infinities, 1e308, 99999999999999999999, 4096 characters,
   ranges of 1e308 points, paths that do not exist, ...).
2. **Files** a user can pass: parameter files (YAML and JSON) with mutated fields, duplicate
   keys and deep nesting, through ``bikeid linearize --bicycle FILE``; model files through
   ``bikeid.ident.effects.pipeline.model_from_json`` and damaged grey-box model files
   through ``bikeid validate --model``; bikeid HDF5 run files with corrupted bytes through
   ``bikeid identify`` and ``bikeid validate``; imported CSV logs with mutated cells through
   ``bikeid.dataset.importers.from_csv``.
3. **Output paths** (:func:`test_output_targets_are_never_clobbered`): a symlink, a FIFO, a
   folder and (where the test may create one) a character device planted at each output.

Every command-line case asserts: exit status 2, 3 or 4 (documented in README, never 1, the
internal-failure status); exactly one line on stderr starting ``bikeid``; no ``Traceback``;
no NaN printed; no file in the working folder created or changed (a resumable sweep's own
``.parts`` folder aside).  API cases assert that only ``ValueError`` or ``OSError`` (with a
message naming the file) escapes.  docs/robustness.md states the counts.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import re
import stat
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bikeid.experiments.cli import build_parser, main

HOSTILE = (
    "", "--", "nan", "NaN", "inf", "-inf", "-1", "0", "1e308", "-1e308", "1e-308", "abc",
    "0:1e308:1e-308", "1:0:1", "0:1:0", "99999999999999999999", "x" * 4096, "\u00e9\u00df",
    "1,,2", ":", "0x10", "5 m/s", "missing/dir/file.h5", "missing.yaml", "1e3", "-0",
)  # fmt: skip
#: Commands that would reach the network with valid arguments: fuzzed with unknown options only.
NETWORK = {("data", "fetch")}
SETTINGS = settings(
    max_examples=80,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    derandomize=True,
)


def _commands() -> list[tuple[tuple[str, ...], list[argparse.Action]]]:
    out = []

    def walk(parser: argparse.ArgumentParser, prefix: tuple[str, ...]) -> None:
        for a in parser._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    walk(sub, (*prefix, name))
                return
        acts = [a for a in parser._actions if a.dest not in ("help", "version")]
        out.append((prefix, acts))

    walk(build_parser(), ())
    return out


COMMANDS = _commands()
#: Fixed arguments of extra command-line variants fuzzed like a command of their own (a mode
#: that reads other inputs): ``measured evaluate --drive logged`` reads an identify model.
VARIANTS = {("measured", "evaluate"): ("--drive=logged",)}
CASES = [(p, (), a) for p, a in COMMANDS] + [
    (p, VARIANTS[p], a) for p, a in COMMANDS if p in VARIANTS
]


def _refused_by_type(action: argparse.Action, value: str) -> bool:
    try:
        action.type(value)
    except Exception:  # noqa: BLE001 - any refusal counts (argparse turns it into usage)
        return True
    return False


def _files(folder: Path) -> dict[str, bytes]:
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = str(p.relative_to(folder))
        if ".parts" in rel:
            continue
        out[rel] = p.read_bytes() if p.is_file() and not p.is_symlink() else b"<other>"
    return out


@contextlib.contextmanager
def _no_default_data():
    """Hide $BIKEID_DATA: a fuzzed command must not fall back to the real data (it would run
    a full computation instead of refusing)."""
    saved = os.environ.pop("BIKEID_DATA", None)
    try:
        yield
    finally:
        if saved is not None:
            os.environ["BIKEID_DATA"] = saved


def _run(argv: list[str], folder: Path) -> tuple[int, str, str]:
    """``main(argv)`` in ``folder`` (every path in the generated cases is relative to it, so
    anything a command creates is seen by the unchanged-files check)."""
    out, err = io.StringIO(), io.StringIO()
    with (
        _no_default_data(), contextlib.chdir(folder), contextlib.redirect_stdout(out),
        contextlib.redirect_stderr(err),
    ):  # fmt: skip
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue()


def _check_refusal(argv: list[str], folder: Path, allowed=(2, 3, 4)) -> tuple[int, str]:
    before = _files(folder)
    rc, out, err = _run(argv, folder)
    assert rc in allowed, (argv, rc, err)
    assert "Traceback" not in err and "Traceback" not in out, (argv, err)
    if rc != 0:
        # the refusal is one line, the last; lines before it may only be the progress lines a
        # long command prints off a terminal ("identify: fitting ..."), never a second error
        lines = err.strip().splitlines()
        assert lines and lines[-1].startswith("bikeid"), (argv, err)
        progress = lines[:-1]
        assert all(re.match(r"^[a-z][\w -]*: ", x) and not x.startswith("bikeid")
                   and "error" not in x.lower() for x in progress), (argv, err)
    assert not re.search(r"\bnan\b", out, re.I), (argv, out)
    assert _files(folder) == before, argv
    return rc, err


def _value_option(acts):
    return [a for a in acts if a.option_strings and a.nargs != 0]


@pytest.mark.parametrize("path,fixed,acts", CASES, ids=[" ".join(p + f) for p, f, _ in CASES])
def test_malformed_command_lines(path, fixed, acts, tmp_path_factory):
    folder = tmp_path_factory.mktemp("fuzz")
    held = {f.split("=")[0] for f in fixed}  # options a variant fixes are not fuzzed
    typed = [a for a in _value_option(acts) if callable(a.type) and a.option_strings[0] not in held]
    others = [a for a in _value_option(acts) if a.option_strings[0] not in held]
    positional = [a for a in acts if not a.option_strings]
    counter = {"n": 0}

    @st.composite
    def argv(draw):
        args = [*path, *fixed]
        refused = None
        if tuple(path) in NETWORK or not (typed or others):
            args.append(draw(st.sampled_from(["--bogus", "--dest=", "-x", "--all-speeds=1"])))
        elif typed:  # one value its own parser refuses: must end in a usage error
            a = draw(st.sampled_from(typed))
            bad = [v for v in HOSTILE if _refused_by_type(a, v)]
            args.append(f"{a.option_strings[0]}={draw(st.sampled_from(bad))}")
            refused = a.option_strings[0]
        else:  # no typed option: a missing input (bicycle, model or data), an input error
            inputs = [a for a in others if a.dest in ("bicycle", "model", "data")] or others
            a = draw(st.sampled_from(inputs))
            args.append(f"{a.option_strings[0]}=missing/{draw(st.sampled_from(HOSTILE))}")
            refused = a.option_strings[0]
        extra = others if tuple(path) not in NETWORK else []  # nothing that could go online
        for a in draw(st.lists(st.sampled_from(extra), max_size=4)) if extra else []:
            if a.option_strings[0] == refused:
                continue  # never override the refused value (argparse keeps the last one)
            args.append(f"{a.option_strings[0]}={draw(st.sampled_from(HOSTILE))}")
        if positional:
            args.append(draw(st.sampled_from(["missing/run.h5", "", "x" * 300])))
        perm = draw(st.permutations(args[len(path) :]))
        return [*path, *perm]

    @SETTINGS
    @given(argv())
    def case(args):
        counter["n"] += 1
        _check_refusal(args, folder)

    case()
    if tuple(path) not in NETWORK:  # (the network commands have only 4 distinct cases)
        assert counter["n"] >= 60  # the budget was spent on real cases
    print(f"{' '.join(path + fixed)}: {counter['n']} generated command lines refused cleanly")


# -- files -----------------------------------------------------------------------------
def _benchmark_params() -> dict:
    from bikeid.sim.parameters import benchmark

    return benchmark().as_dict()


WEIRD = st.one_of(
    st.booleans(), st.none(), st.text(max_size=20), st.just([1]), st.just({"a": 1}),
    st.sampled_from([1e308, -1e308, 0.0, -1.0, 1e-300, 1e200, 2**70]),
    st.floats(allow_nan=False, allow_infinity=False),
)  # fmt: skip


@pytest.mark.slow
@SETTINGS
@given(
    changes=st.dictionaries(st.sampled_from(sorted(_benchmark_params())), WEIRD, max_size=3),
    fmt=st.sampled_from(["yaml", "json"]),
    extra=st.sampled_from(["", "dup", "deep", "junk", "nan"]),
)
def test_malformed_parameter_files(changes, fmt, extra):
    import yaml

    params = {k: v for k, v in _benchmark_params().items() if k != "name"} | changes
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        f = folder / f"bike.{fmt}"
        text = json.dumps(params) if fmt == "json" else yaml.safe_dump(params)
        if extra == "dup":
            text = (text.replace("{", '{"w": 1.02, ', 1) if fmt == "json"
                    else text + "w: 1.02\nw: 1.03\n")  # fmt: skip
        elif extra == "deep":
            text = "[" * 5000 + "]" * 5000
        elif extra == "junk":
            text = text[: len(text) // 2]
        elif extra == "nan":
            text = text.replace("1.02", "NaN" if fmt == "json" else ".nan", 1)
        f.write_text(text)
        rc, _ = _check_refusal(["linearize", f"--bicycle={f}", "--speed=5"], folder, (0, 3))
        if not changes and extra == "":
            assert rc == 0


@SETTINGS
@given(
    doc=st.recursive(
        st.one_of(st.none(), st.booleans(), st.floats(), st.text(max_size=8)),
        lambda c: st.one_of(st.lists(c, max_size=3), st.dictionaries(st.text(max_size=12), c)),
        max_leaves=12,
    ),
    base=st.booleans(),
)
def test_malformed_model_files(doc, base):
    """Model files (``measured fit`` output): anything but a valid model is a ValueError."""
    from bikeid.ident.effects.pipeline import model_from_json

    if base and isinstance(doc, dict):
        doc = {"effects": {"steer_viscous_damping": 0.3}, "plant": "linear", "K": 2.0} | doc
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "model.json"
        f.write_text(json.dumps(doc))
        try:
            model_from_json(f)
        except ValueError as exc:
            assert str(exc), "empty message"


def _greybox_text(dt: float) -> str:
    """A valid grey-box model file (benchmark matrices, three free entries)."""
    from bikeid.ident.greybox import GreyboxModel
    from bikeid.ident.model_file import model_json
    from bikeid.sim.linear import canonical_matrices
    from bikeid.sim.parameters import benchmark

    cm = canonical_matrices(benchmark())
    free = {"Mpd": cm.M[0, 1], "K0dd": cm.K0[1, 1], "K2dd": cm.K2[1, 1]}
    return model_json(GreyboxModel(
        M=cm.M, C1=cm.C1, K0=cm.K0, K2=cm.K2, g=cm.g, H=np.zeros(2), free=free,
        stderr=dict.fromkeys(free, 1e-3), covariance=np.eye(3) * 1e-6, condition=10.0,
        inflation=dict.fromkeys(free, 1.0), weakest=dict.fromkeys(free, 0.5), dropped=(),
        fixed={"Mpp": cm.M[0, 0]}, symmetric=True, K={5.0: np.zeros((4, 4))}, dt=dt,
        outputs=("phi", "phidot", "delta", "deltadot"), speeds=(5.0,),
        noise_covariance=np.eye(4) * 1e-6,
    ))  # fmt: skip


@settings(
    max_examples=40,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data())
def test_damaged_model_files_through_validate(run_file, data):
    """A grey-box model file (``identify --method greybox --out``) with one field at any depth
    replaced by a hostile JSON value, through ``bikeid validate --model``: status 0, 3 or 4,
    one line, no traceback, nothing written."""
    obj = json.loads(_greybox_text(0.01))
    paths = []

    def walk(node, prefix):
        paths.append(prefix)
        if isinstance(node, dict):
            for k, v in node.items():
                walk(v, (*prefix, k))
        elif isinstance(node, list):
            for k, v in enumerate(node):
                walk(v, (*prefix, k))

    walk(obj, ())
    path = data.draw(st.sampled_from(paths[1:]))
    hostile = st.one_of(st.none(), st.booleans(), st.text(max_size=6), st.just([]),
                        st.just({}), st.sampled_from([1e308, -1.0, 0.0, 2**70]))  # fmt: skip
    value = data.draw(hostile)
    node = obj
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value
    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "runs.h5").write_bytes(run_file)
        (Path(d) / "m.json").write_text(json.dumps(obj))
        _check_refusal(["validate", "runs.h5", "--model=m.json"], Path(d), (0, 3, 4))


@pytest.fixture(scope="module")
def run_file(tmp_path_factory) -> bytes:
    from bikeid.dataset.linear_loop import simulate
    from bikeid.dataset.store import write_runs
    from bikeid.sim.parameters import benchmark

    f = tmp_path_factory.mktemp("runs") / "runs.h5"
    write_runs(f, [simulate(benchmark(), 5.0, duration=2.0, seed=1)])
    return f.read_bytes()


@settings(
    max_examples=40,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data(), command=st.sampled_from(["identify", "validate"]))
def test_corrupted_run_files(run_file, data, command):
    """bikeid HDF5 run files with bytes overwritten: ``identify`` and ``validate`` refuse
    cleanly (or, when the damage misses everything they read, succeed without NaN)."""
    raw = bytearray(run_file)
    for _ in range(data.draw(st.integers(1, 8))):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):
        raw = raw[: data.draw(st.integers(0, len(raw)))]
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "runs.h5"
        f.write_bytes(bytes(raw))
        if command == "identify":
            _check_refusal(["identify", str(f), "--method=direct"], Path(d), (0, 3, 4))
        else:
            (Path(d) / "m.json").write_text(_greybox_text(0.01))
            _check_refusal(["validate", str(f), "--model=m.json"], Path(d), (0, 3, 4))


@SETTINGS
@given(
    cells=st.lists(
        st.tuples(st.integers(1, 40), st.integers(0, 5),
                  st.sampled_from(["", "nan", "inf", "x", "1e400", "--", '"', "1,2"])),
        min_size=1, max_size=4,
    )
)  # fmt: skip
def test_malformed_imported_csv(cells):
    """A user's CSV log with damaged cells: only ValueError / OSError, naming the file."""
    from bikeid.dataset.importers import from_csv

    t = np.arange(60) * 0.01
    cols = {"time": t, "roll": 0.01 * np.sin(t), "steer": 0.02 * np.cos(t),
            "roll_rate": 0.01 * np.cos(t), "steer_rate": -0.02 * np.sin(t),
            "torque": 0.1 * np.sin(3 * t)}  # fmt: skip
    rows = [",".join(cols)] + [",".join(f"{cols[c][i]:.17g}" for c in cols) for i in range(60)]
    for r, c, v in cells:
        parts = rows[r].split(",")
        parts[c] = v
        rows[r] = ",".join(parts)
    mapping = {"phi": "roll", "delta": "steer", "phidot": "roll_rate",
               "deltadot": "steer_rate", "T_delta": "torque"}  # fmt: skip
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "log.csv"
        f.write_text("\n".join(rows) + "\n")
        try:
            run = from_csv(f, mapping, time="time", speed=4.0)
        except (ValueError, OSError) as exc:
            assert "log.csv" in str(exc), str(exc)
        else:
            assert all(np.all(np.isfinite(x)) for x in run.signals.values())


# -- output targets ---------------------------------------------------------------------
OUTPUTS = {
    "eig --plot": lambda out: ["eig", "--speeds=0:2:1", f"--plot={out}"],
    "simulate --out": lambda out: ["simulate", "--speed=5", "--duration=0.1", f"--out={out}"],
    "sweep --out": lambda out: [
        "sweep",
        "--controller=pid",
        "--speeds=5",
        "--duration=0.2",
        "--seeds=0",
        "--no-progress",
        f"--out={out}",
    ],
    "validate --out": lambda out: ["validate", "runs.h5", "--model=m.json", f"--out={out}"],
}


def _plant(kind: str, target: Path, sentinel: Path) -> None:
    if kind == "symlink":
        target.symlink_to(sentinel)
    elif kind == "fifo":
        os.mkfifo(target)
    elif kind == "folder":
        target.mkdir()
    elif kind == "device":
        try:  # the same device numbers as /dev/null; needs root (CAP_MKNOD)
            os.mknod(target, 0o600 | stat.S_IFCHR, os.makedev(1, 3))
        except (PermissionError, OSError) as exc:
            pytest.skip(f"cannot create a character device here ({exc}); the symlink, FIFO "
                        "and folder cases cover the same refusal")  # fmt: skip


def _validate_inputs(folder: Path) -> None:
    """A short run file and a grey-box model file for ``validate``."""
    from bikeid.dataset.linear_loop import simulate
    from bikeid.dataset.store import write_runs
    from bikeid.sim.parameters import benchmark

    run = simulate(benchmark(), 5.0, duration=2.0, seed=1)
    write_runs(folder / "runs.h5", [run])
    (folder / "m.json").write_text(_greybox_text(run.dt))


# a folder is what validate --out writes into, so it is no hostile target there
TARGETS = [(c, k) for c in sorted(OUTPUTS) for k in ("symlink", "fifo", "folder", "device")
           if not (c == "validate --out" and k == "folder")]  # fmt: skip


@pytest.mark.parametrize("command, kind", TARGETS)
def test_output_targets_are_never_clobbered(command, kind, tmp_path):
    """A symlink, FIFO, folder or device at an output path is refused (status 3) and left
    as it was; the symlink's target (a user's file) is untouched."""
    suffix = {"eig --plot": ".png", "simulate --out": ".csv", "sweep --out": ".h5",
              "validate --out": ""}[command]  # fmt: skip
    if command == "validate --out":
        _validate_inputs(tmp_path)
    target = tmp_path / f"out{suffix}"
    sentinel = tmp_path / "precious.txt"
    sentinel.write_text("a user's data")
    _plant(kind, target, sentinel)
    mode = os.lstat(target).st_mode
    rc, out, err = _run(OUTPUTS[command](target), tmp_path)
    assert rc == 3, (rc, err)
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert sentinel.read_text() == "a user's data"
    assert os.lstat(target).st_mode == mode  # still the planted thing
    leftovers = [p.name for p in tmp_path.iterdir() if p.name.startswith(".") and "tmp" in p.name]
    assert not leftovers, leftovers


@pytest.mark.parametrize("command", ["eig --plot", "simulate --out"])
def test_foreign_regular_file_is_replaced_atomically_keeping_its_mode(command, tmp_path):
    """An existing regular file at the output is the user's request to overwrite it: it is
    replaced whole (never half-written), keeping its permission bits."""
    suffix = {"eig --plot": ".png", "simulate --out": ".csv", "sweep --out": ".h5"}[command]
    target = tmp_path / f"out{suffix}"
    target.write_bytes(b"old")
    os.chmod(target, 0o640)
    rc, _, err = _run(OUTPUTS[command](target), tmp_path)
    assert rc == 0, err
    assert target.read_bytes() != b"old"
    assert stat.S_IMODE(os.stat(target).st_mode) == 0o640
