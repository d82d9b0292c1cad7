"""No traceback from any input: every failure of ``bikeid`` is one line and a documented
exit status (``bikeid --help``; :mod:`bikeid.sim.errors`):

0 success, 1 internal failure, 2 usage error (argparse), 3 invalid input data or
parameters, 4 no trustworthy answer.

Each case runs ``main([...])`` in process and asserts the status, a one-line message that
names the problem, no traceback, and that no output file was created or changed.  The
inputs are the ones that escaped ``main()`` as tracebacks (or passed silently) before.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from bikeid.experiments.cli import main
from bikeid.sim.errors import (
    EXIT_INPUT,
    EXIT_INTERNAL,
    EXIT_UNTRUSTWORTHY,
    EXIT_USAGE,
    InputError,
    UntrustworthyResult,
    check_memory,
    memory_limit,
)
from bikeid.sim.parameters import PLAUSIBLE_LIMIT, benchmark, from_file
from bikeid.sim.textformats import MAX_DEPTH, loads_json, loads_yaml


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() if p.is_file() else b"<dir>"
            for p in sorted(folder.rglob("*"))}  # fmt: skip


def fails(capsys, tmp_path: Path, argv: list[str], code: int, *phrases: str) -> str:
    """Run ``main(argv)``: exit ``code``, one stderr line holding every phrase, no
    traceback, and the files under ``tmp_path`` unchanged (none created, none changed)."""
    before = _files(tmp_path)
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == code, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert lines[0].startswith("bikeid"), err
    assert ": error: " in lines[0], err
    for phrase in phrases:
        assert phrase in lines[0], (phrase, err)
    assert _files(tmp_path) == before
    return lines[0]


# -- exit codes -------------------------------------------------------------------------
def test_help_documents_exit_codes(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for line in ("0  success", "1  internal failure", "2  usage error",
                 "3  invalid input", "4  no trustworthy answer"):  # fmt: skip
        assert line in out
    assert (EXIT_INTERNAL, EXIT_USAGE, EXIT_INPUT, EXIT_UNTRUSTWORTHY) == (1, 2, 3, 4)


def test_error_types_stay_value_errors():
    """Existing ``except ValueError`` code keeps catching both."""
    assert issubclass(InputError, ValueError) and issubclass(UntrustworthyResult, ValueError)


@pytest.mark.parametrize(
    ("exc", "code", "phrase"),
    [
        (None, 0, None),
        (InputError("bad field x"), EXIT_INPUT, "bikeid eig: error: bad field x"),
        (ValueError("plain value error"), EXIT_INPUT, "bikeid eig: error: plain value error"),
        (FileNotFoundError(2, "No such file or directory", "f.h5"), EXIT_INPUT, "'f.h5'"),
        (MemoryError(), EXIT_INPUT, "out of memory"),
        (OverflowError("math range error"), EXIT_INPUT, "too large"),
        (UntrustworthyResult("row is unidentifiable"), EXIT_UNTRUSTWORTHY, "unidentifiable"),
        (
            RuntimeError("boom"),
            EXIT_INTERNAL,
            "internal error (RuntimeError): boom; rerun with --debug and report it",
        ),
    ],
)
def test_exception_to_exit_code(monkeypatch, capsys, exc, code, phrase):
    """The mapping of :mod:`bikeid.sim.errors`, each status on a case known to give it
    (success included), through a handler that raises."""
    from bikeid.experiments.cli import plant as cmd_plant

    def handler(args):
        if exc is not None:
            raise exc
        return 0

    monkeypatch.setattr(cmd_plant, "cmd_eig", handler)
    assert main(["eig"]) == code
    err = capsys.readouterr().err
    if phrase is None:
        assert err == ""
    else:
        assert phrase in err and len(err.strip().splitlines()) == 1
        assert "Traceback" not in err


def test_debug_prints_the_traceback(monkeypatch, capsys):
    from bikeid.experiments.cli import plant as cmd_plant

    def handler(args):
        raise RuntimeError("boom")

    monkeypatch.setattr(cmd_plant, "cmd_eig", handler)
    assert main(["eig", "--debug"]) == EXIT_INTERNAL
    err = capsys.readouterr().err
    assert "Traceback" in err and "RuntimeError: boom" in err
    assert err.strip().splitlines()[-1].startswith("bikeid eig: internal error (RuntimeError)")


# -- usage errors (2): argparse type= checks name the option, value and range ------------
@pytest.mark.parametrize(
    ("argv", "phrases"),
    [
        (["simulate", "--speed", "5", "--duration=--", "--out", "x.csv"],
         ("argument --duration", "expected one value, got '--'")),
        (["simulate", "--speed", "5", "--duration", "nan", "--out", "x.csv"],
         ("argument --duration", "'nan' is not finite")),
        (["simulate", "--speed", "5", "--duration", "1", "--fall-limit", "100", "--out",
          "x.csv"], ("argument --fall-limit", "100 deg is out of range", "<= 90 deg")),
        (["simulate", "--speed", "-1", "--duration", "1", "--out", "x.csv"],
         ("argument --speed", ">= 0 m/s")),
        (["linearize", "--speed", "1e308"], ("argument --speed", "<= 100 m/s")),
        (["eig", "--speeds", "0:1e308:1e-308"], ("argument --speeds", "at most 1,000,000")),
        (["eig", "--speeds", "0:200:1"], ("argument --speeds", "values must be <= 100")),
        (["sweep", "--controller", "pid", "--workers", "99999999999999999999", "--out",
          "x.h5"], ("argument --workers", "<= 1024")),
        (["sweep", "--controller", "pid", "--workers", "0", "--out", "x.h5"],
         ("argument --workers", ">= 1")),
        (["sweep", "--controller", "pid", "--seeds", "0.5,1", "--out", "x.h5"],
         ("argument --seeds", "seeds must be integers")),
        (["sweep", "--controller", "pid", "--rate", "inf", "--out", "x.h5"],
         ("argument --rate", "not finite")),
        (["accuracy", "--workers", "1e3"], ("argument --workers", "not a whole number")),
        (["measured", "fit", "--out", "m.json", "--stability", "-1"],
         ("argument --stability", ">= 0")),
        (["measured", "fit", "--out", "m.json", "--weave-weight", "-2"],
         ("argument --weave-weight", "'auto' or a number >= 0")),
        (["measured", "fit", "--out", "m.json", "--min-heldout-gain", "1"],
         ("argument --min-heldout-gain", "out of range", "need >= 0 and < 1")),
        (["measured", "fit", "--out", "m.json", "--min-heldout-gain", "-0.1"],
         ("argument --min-heldout-gain", "need >= 0 and < 1")),
        (["measured", "fit", "--out", "m.json", "--min-improved", "1.5"],
         ("argument --min-improved", "need >= 0 and <= 1")),
        (["measured", "fit", "--out", "m.json", "--unexplained-threshold", "0"],
         ("argument --unexplained-threshold", "need > 0")),
        (["measured", "fit", "--out", "m.json", "--unexplained-rule", "vibes"],
         ("argument --unexplained-rule", "invalid choice")),
        (["measured", "trials", "--min-improved", "nan"],
         ("argument --min-improved", "not finite")),
        (["reproduce", "--workers", "x"], ("argument --workers", "'x' is not a whole number")),
    ],
)  # fmt: skip
def test_bad_option_values_are_usage_errors(capsys, tmp_path, monkeypatch, argv, phrases):
    monkeypatch.chdir(tmp_path)
    fails(capsys, tmp_path, argv, EXIT_USAGE, *phrases)


# -- input too large for memory (3): refused with the size, before any file is made -----
def test_simulate_too_long_is_refused_with_its_size(capsys, tmp_path):
    out = tmp_path / "run.csv"
    argv = ["simulate", "--speed", "5", "--duration", "1e12", "--out", str(out)]
    fails(capsys, tmp_path, argv, EXIT_INPUT, "PiB", "samples x 37 channels", "shorten")


def test_sweep_too_long_leaves_no_parts_folder(capsys, tmp_path):
    out = tmp_path / "x.h5"
    fails(capsys, tmp_path, ["sweep", "--controller", "pid", "--speeds", "5", "--seeds", "0",
                             "--duration", "1e12", "--no-progress", "--out", str(out)],
          EXIT_INPUT, "PiB", "shorten --duration")  # fmt: skip
    assert not out.exists() and not (tmp_path / "x.h5.parts").exists()


def test_memory_check_both_ways():
    """Known both ways: a 50 s run at 100 Hz (5001 x 45 x 8 B = 1.8 MB) passes; one
    larger than the limit by a sample is refused, naming both sizes."""
    check_memory(5001, 45, "a run", "shorten it")
    limit = memory_limit()
    check_memory(limit // 8, 1, "a run", "shorten it")
    with pytest.raises(InputError, match=r"needs .* more than the .* allowed"):
        check_memory(limit // 8 + 1, 1, "a run", "shorten it")
    with pytest.raises(InputError, match="needs inf PiB"):
        check_memory(math.inf, 1, "a run", "shorten it")


def test_sweep_refuses_a_non_hdf5_out_without_touching_it(capsys, tmp_path):
    out = tmp_path / "x.h5"
    out.write_text("my notes\n")
    fails(capsys, tmp_path, ["sweep", "--controller", "pid", "--speeds", "5", "--seeds", "0",
                             "--duration", "1", "--no-progress", "--out", str(out)],
          EXIT_INPUT, "is not an HDF5 file", "delete or rename")  # fmt: skip
    assert not (tmp_path / "x.h5.parts").exists()


def test_identify_message_on_a_non_hdf5_file(capsys, tmp_path):
    """The message no longer promises that a rerun rebuilds the file (the rerun refused)."""
    f = tmp_path / "runs.h5"
    f.write_text("text\n")
    line = fails(capsys, tmp_path, ["identify", str(f)], EXIT_INPUT, "not a readable HDF5")
    assert "rebuilds" not in line and "delete or rename" in line


@pytest.mark.parametrize(
    ("argv", "phrase"),
    [
        (["--plant", "linear", "--critical"], "--plant and --critical are separate studies"),
        (["--restart"], "--noise-model and --restart apply to --plant"),
        (["--noise-model", "none"], "--noise-model and --restart apply to --plant"),
    ],
)  # fmt: skip
def test_coverage_refuses_options_of_another_study(capsys, tmp_path, argv, phrase):
    """An option of one coverage study given to another is refused, not silently ignored
    (the default-path options were dropped by the linear study, --plant by --critical)."""
    fails(capsys, tmp_path, ["coverage", "--seeds", "2", *argv], EXIT_INPUT, phrase)


# -- parameter files (3) ----------------------------------------------------------------
def _param_file(tmp_path: Path, text: str, name: str = "bike.json") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _with(**changes) -> str:
    values = benchmark().as_dict()
    values.update(changes)
    return json.dumps(values)


@pytest.mark.parametrize(
    ("text", "name", "phrases"),
    [
        (_with(mB=True), "b.json", ("'mB' must be a real number [kg], got True",)),
        (_with(mB="85"), "b.json", ("'mB' must be a real number", "'85'")),
        (_with(IRzz=[1]), "b.json", ("'IRzz' must be a real number", "[1]")),
        (_with(w=1e200), "b.json", ("w=1e+200", "need |w| < 10 m")),
        (_with(mB=1e308), "b.json", ("mB=1e+308", "need |mB| < 1000 kg")),
        (_with(IBxx=5e3), "b.json", ("IBxx=5000.0", "need |IBxx| < 1000 kg m^2")),
        (_with(mH=1e308), "b.json", ("mH=1e+308",)),  # was numpy's "must not contain infs"
        (_with(g=1e308), "b.json", ("g=1e+308", "< 100 m/s^2")),
        (_with()[:-1] + ', "mB": 90}', "b.json", ("key 'mB' appears twice",)),
        ("w: 1.02\nw: 1.03\n", "b.yaml", ("key 'w' appears twice (line 2)",)),
        (_with()[:-1] + ', "mB": NaN}', "b.json", ("NaN is not a number JSON allows",)),
        ("[" * 100_000 + "]" * 100_000, "b.json", ("nested 100000 levels deep",)),
        ("[" * 100_000 + "]" * 100_000, "b.yaml", ("nested more than 64 levels deep",)),
        ("".join(" " * i + "k:\n" for i in range(1000)), "b.yaml", ("nested",)),  # block style
        ("{", "b.json", ("is not valid JSON", "line 1 column 2")),
        ("a: [1", "b.yaml", ("is not valid YAML",)),
        ("[1, 2]", "b.json", ("must hold a mapping", "got list")),
    ],
)  # fmt: skip
def test_bad_parameter_file(capsys, tmp_path, text, name, phrases):
    path = _param_file(tmp_path, text, name)
    line = fails(capsys, tmp_path, ["critical-speeds", "--bicycle", str(path)], EXIT_INPUT,
                 f"parameter file '{path}'", *phrases)  # fmt: skip
    assert len(line) < 400


def test_plausible_ranges_both_ways(tmp_path):
    """Just inside each limit is accepted (the rest of the rules permitting), the limit
    itself refused, naming the parameter."""
    assert PLAUSIBLE_LIMIT == {"m": 10.0, "kg": 1000.0, "kg m^2": 1000.0, "m/s^2": 100.0}
    p = benchmark()
    assert p.replace(mB=999.0).mB == 999.0 and p.replace(g=99.0).g == 99.0
    for key, value in (("mB", 1000.0), ("g", 100.0), ("w", 10.0), ("xB", -10.0)):
        with pytest.raises(InputError, match=rf"parameter {key}="):
            p.replace(**{key: value})
    ok = _param_file(tmp_path, _with(mB=90))
    assert from_file(ok).mB == 90.0  # the strict reader still reads a good file


def test_strict_readers_accept_what_bikeid_writes():
    """Known both ways: nesting up to MAX_DEPTH and brackets inside strings are fine."""
    deep = "[" * MAX_DEPTH + "]" * MAX_DEPTH
    assert loads_json(deep, "x") is not None and loads_yaml(deep, "x") is not None
    assert loads_json('{"a": "' + "[" * 200 + '\\""}', "x") == {"a": "[" * 200 + '"'}
    assert loads_yaml("a: 1\nb: {a: 2}\n", "x") == {"a": 1, "b": {"a": 2}}
    with pytest.raises(InputError, match="nested 65 levels"):
        loads_json("[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1), "x")


# -- model files (3) --------------------------------------------------------------------
@pytest.mark.parametrize(
    ("obj", "phrases"),
    [
        ({"effects": {}, "fit_speeds": "abc"}, ("'fit_speeds' must be a list",)),
        ({"effects": {}, "fit_speeds": [True]}, ("'fit_speeds' must be a list",)),
        ({"effects": {}, "fit_speeds": None}, ("'fit_speeds' must be a list",)),
        ({"effects": {}, "plant": "quantum"}, ("'plant' is 'quantum'", "'nonlinear', 'linear'")),
        ({"effects": {"steer_stiffness": True}}, ("effect steer_stiffness must be a number",)),
        ({"effects": {"steer_stiffness": 1e9}}, ("outside its plausible range",)),
        ({"effects": {"warp_drive": 1.0}}, ("unknown effect 'warp_drive'",)),
        ({"effects": [1]}, ("'effects' must be an object",)),
        ({"plant": "linear"}, ("'effects' must be an object", "got nothing")),
        ({"effects": {}, "identification": 3}, ("'identification' must be the object",)),
        ([1], ("must hold a JSON object",)),
    ],
)  # fmt: skip
def test_bad_model_file(capsys, tmp_path, obj, phrases):
    model = tmp_path / "m.json"
    model.write_text(json.dumps(obj))
    argv = ["measured", "evaluate", "--model", str(model), "--data", str(tmp_path)]
    fails(capsys, tmp_path, argv, EXIT_INPUT, f"model file '{model}'", *phrases)


def test_model_duplicate_and_deep(capsys, tmp_path):
    model = tmp_path / "m.json"
    model.write_text('{"effects": {}, "effects": {"steer_stiffness": 1}}')
    fails(capsys, tmp_path, ["measured", "evaluate", "--model", str(model)], EXIT_INPUT,
          "key 'effects' appears twice")  # fmt: skip
    model.write_text('{"effects": ' + "[" * 10_000 + "]" * 10_000 + "}")
    fails(capsys, tmp_path, ["measured", "evaluate", "--model", str(model)], EXIT_INPUT,
          "nested 10001 levels deep")  # fmt: skip


def test_model_without_plant_defaults_like_fit(tmp_path):
    """A model file without ``plant`` is evaluated with the nonlinear plant, the plant
    ``measured fit`` used before it recorded one (its default is now ``auto``, which writes
    the plant it chose), and says so."""
    import inspect

    from bikeid.ident.effects.pipeline import DEFAULT_PLANT, fit_model, model_from_json

    assert inspect.signature(fit_model).parameters["plant"].default == "auto"
    assert DEFAULT_PLANT == "nonlinear"
    model = tmp_path / "m.json"
    model.write_text(json.dumps({"effects": {"steer_viscous_damping": 0.4}}))
    _, obj = model_from_json(model)
    assert obj["plant"] == "nonlinear" and obj["plant_defaulted"] is True
    model.write_text(json.dumps({"effects": {}, "plant": "linear"}))
    _, obj = model_from_json(model)
    assert obj["plant"] == "linear" and "plant_defaulted" not in obj


# -- measured logs (3) ------------------------------------------------------------------
HEADER = ("sil_command,speed,lean_angle,lean_rate,hand_angle,fork_angle,fork_rate,lean_torque,"
          "hand_torque,x_acceleration,y_acceleration,command_fork,command_hand")  # fmt: skip


@pytest.mark.parametrize(
    ("field", "phrases"),
    [
        # csv's default field limit is 131,072 characters: one more is a csv.Error
        ("9" * 131_073, ("eigen_x_3mps.log: line 22", "field larger than field limit")),
        # exactly at the limit it parses, to inf
        ("9" * 131_072, ("row 22, column 'lean_angle': non-finite value inf",)),
        ("x" * 131_072, ("row 22, column 'lean_angle': non-numeric value", "131,072 characters")),
    ],
)
def test_log_with_a_huge_field(capsys, tmp_path, field, phrases):
    eigen = tmp_path / "tudelft-sbw" / "eigen"
    eigen.mkdir(parents=True)
    rows = ["1,3.0,0,0,0,0,0,0,0,0,0,1,0"] * 50
    rows[20] = f"1,3.0,{field},0,0,0,0,0,0,0,0,1,0"
    (eigen / "eigen_x_3mps.log").write_text(HEADER + "\n" + "\n".join(rows) + "\n")
    line = fails(capsys, tmp_path, ["measured", "fit", "--data", str(tmp_path), "--out",
                                    str(tmp_path / "m.json")], EXIT_INPUT, *phrases)  # fmt: skip
    assert len(line) < 400


# -- untrustworthy answers (4) ----------------------------------------------------------
def test_short_runs_name_the_filter_not_padlen(tmp_path):
    """scipy's 'padlen' message became one naming the run length and the fix."""
    import numpy as np
    from scipy.signal import butter, sosfiltfilt

    from bikeid.ident.signals import lowpass

    with pytest.raises(InputError, match=r"a run of 9 samples is too short .*\(cutoff 0\)"):
        lowpass(np.zeros(9), 0.01, 3.0)
    # the bound is scipy's own: it refuses 9 samples and filters 10 (second-order filter)
    with pytest.raises(ValueError, match="padlen"):
        sosfiltfilt(butter(2, 0.06, output="sos"), np.zeros(9))
    assert lowpass(np.zeros(10), 0.01, 3.0).shape == (10,)


def test_unidentifiable_is_exit_4(monkeypatch, capsys, tmp_path):
    """An estimator's refusal reaches the user as status 4 with its message, here the
    direct method's conditioning refusal (raised by ``ident.direct``)."""
    import bikeid.ident.direct as direct
    from bikeid.experiments.cli import identify as cmd_ident

    def refuse(*args, **kwargs):
        raise UntrustworthyResult("roll row is unidentifiable: condition number 1e+13")

    monkeypatch.setattr(direct, "identify", refuse)
    monkeypatch.setattr(cmd_ident, "_truth", lambda runs: benchmark())
    import bikeid.dataset.store as store
    from bikeid.dataset.linear_loop import simulate

    run = simulate(benchmark(), 5.0, duration=5.0)  # dithered: passes the data checks
    monkeypatch.setattr(store, "read_runs", lambda path, truth=True: [run])
    import bikeid.ident.signals as signals

    monkeypatch.setattr(signals, "prepare", lambda run, **kw: run)
    fails(capsys, tmp_path, ["identify", "x.h5", "--method", "direct", "--quiet"],
          EXIT_UNTRUSTWORTHY, "unidentifiable")


def test_report_refuses_a_bad_model_before_making_its_folder(capsys, tmp_path):
    model = tmp_path / "m.json"
    model.write_text(json.dumps({"effects": {}, "plant": "quantum"}))
    argv = ["measured", "report", "--model", str(model), "--out", str(tmp_path / "rep")]
    fails(capsys, tmp_path, argv, EXIT_INPUT, "'plant' is 'quantum'")
    assert not (tmp_path / "rep").exists()


# -- property: arbitrary text never escapes as anything but the documented errors -------

_TEXT = st.one_of(
    st.text(max_size=40),
    st.from_regex(r"-?[0-9e.:,+-]{0,30}|nan|inf|-inf|1e3\d\d", fullmatch=True),
)


@settings(max_examples=300, deadline=None)
@given(_TEXT)
def test_argument_types_raise_only_usage_errors(text):
    """Every argument type either returns a finite value in its range or raises
    ArgumentTypeError (argparse turns it into exit status 2)."""
    import argparse

    from bikeid.experiments.cli.args import MAX_SPEED, integer, range_text, speed_value

    for parse in (speed_value, integer(1, 1024), range_text("--speeds", 0.0)):
        try:
            value = parse(text)
        except argparse.ArgumentTypeError:
            continue
        if parse is speed_value:
            assert math.isfinite(value) and 0 <= value <= MAX_SPEED
        elif isinstance(value, int):
            assert 1 <= value <= 1024


@settings(max_examples=300, deadline=None)
@given(st.text(alphabet='{}[]":,1aN\\ \n-', max_size=200))
@example("[]:")  # a list as a YAML mapping key: was a TypeError (found by this test in CI)
@example("{a: 1}: 2")
def test_strict_readers_raise_only_input_errors(text):
    """Any text: JSON and YAML readers return a value or raise InputError (exit 3)."""
    for load in (loads_json, loads_yaml):
        try:
            load(text, "f")
        except InputError:
            pass
