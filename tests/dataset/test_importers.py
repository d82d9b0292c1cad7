"""Importers: a user's CSV / HDF5 / data-frame logs become a Run, or a clear one-line error.

References:

- round trips: a simulated run (``dataset.linear_loop``) written by the existing
  ``store.export_csv`` (17 significant digits, which round-trips float64 exactly, so SI
  columns must come back bit for bit) or by h5py (float64 datasets: bit for bit);
- unit conversions: copies written by the test in deg, deg/s, km/h, N cm, ms: value / f
  with 17 significant digits (exact), and the importer multiplies by the same float f.
  Two roundings of at most half an ulp each bound the relative error by eps (2.2e-16;
  measured maximum 0.98 eps over 50 000 random values for every unit); the tolerance is
  ``RTOL = 2 eps``;
- errors: files made bad in a known row and column; each message must name the file, the
  column and the row (CSV: the 1-based line number a spreadsheet shows, comment and header
  lines counted).
"""

from __future__ import annotations

import hashlib
import json
import math
import tempfile
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bikeid.dataset.importers import CONVERSIONS, from_csv, from_dataframe, from_hdf5
from bikeid.dataset.store import export_csv
from bikeid.sim.conventions import UNITS

RTOL = 2 * np.finfo(float).eps  # two half-ulp roundings per value, module docstring
SIGNALS = ("phi", "delta", "phidot", "deltadot", "v", "T_delta", "psi", "psidot")
CORE = ("phi", "delta", "phidot", "deltadot", "T_delta")


@pytest.fixture(scope="module")
def sim_run():
    from bikeid.dataset.linear_loop import simulate
    from bikeid.sim.parameters import benchmark

    return simulate(benchmark(), 4.5, duration=5.0, seed=1, angle_noise=1e-3, rate_noise=1e-3)


def export_mapping(keys=SIGNALS) -> dict[str, str]:
    """bikeid signal -> the header export_csv writes for it."""
    return {k: f"{k} [{UNITS[k]}]" for k in keys}


# -- a small synthetic log for the error cases ------------------------------------------
N = 40
DT = 0.01


def good_table() -> dict[str, np.ndarray]:
    t = np.arange(N) * DT
    return {
        "time": t,
        "roll": np.sin(3 * t),
        "steer": np.cos(2 * t),
        "rollrate": 3 * np.cos(3 * t),
        "steerrate": -2 * np.sin(2 * t),
        "speed": 4.5 + 0.01 * np.sin(t),
        "torque": np.sin(7 * t),
        "note": np.zeros(N),
    }


MAP = {
    "phi": "roll", "delta": "steer", "phidot": "rollrate", "deltadot": "steerrate",
    "v": "speed", "T_delta": "torque",
}  # fmt: skip

#: Data row i of write_csv's files is on line i + FIRST (line 1 comment, line 2 header).
FIRST = 3


def write_csv(path: Path, table: dict, *, cells: dict | None = None, header=None) -> Path:
    """A comment line, a header line, then N rows; ``cells[(i, col)]`` overrides a cell."""
    cols = list(table) if header is None else header
    lines = ["# my bike, logged 2026-11-24", ",".join(cols)]
    names = list(table)
    for i in range(len(table[names[0]])):
        row = [repr(float(table[c][i])) for c in names]
        for (j, c), text in (cells or {}).items():
            if j == i:
                row[names.index(c)] = text
        lines.append(",".join(row))
    path.write_text("\n".join(lines) + "\n")
    return path


def read(path, **kw):
    kw.setdefault("time", "time")
    return from_csv(path, MAP, **kw)


def assert_names(msg: str, *parts: str) -> None:
    for p in parts:
        assert p in msg, f"{p!r} not in message: {msg}"
    assert "\n" not in msg, "messages are one line"


# -- round trips ---------------------------------------------------------------------------
def test_csv_round_trip_is_exact(sim_run, tmp_path):
    path = export_csv(sim_run, tmp_path / "run.csv")
    run = from_csv(path, export_mapping(), time="t [s]")
    assert np.array_equal(run.t, sim_run.t)
    for k in SIGNALS:  # 17 significant digits round-trip float64 exactly
        assert np.array_equal(run.signals[k], sim_run.signals[k]), k
    assert run.speed == pytest.approx(4.5, rel=1e-15)  # v is the constant 4.5 m/s
    imp = run.meta["import"]
    assert run.meta["source"] == "imported"
    assert imp["file"] == "run.csv"
    assert imp["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    assert imp["columns"] == export_mapping()
    assert imp["format"] == "csv" and imp["speed_source"] == "column"
    assert imp["units"]["phi"] == {"from": "rad", "to": "rad", "factor": 1.0}
    json.dumps(run.meta)


def _converted_copy(sim_run, path: Path, units: dict, flip=(), time_unit="s") -> Path:
    """Write sim_run in the given user units (and flipped signs), 17 significant digits."""
    cols = {"time": sim_run.t / CONVERSIONS["s"][time_unit]}
    for k in SIGNALS:
        x = sim_run.signals[k] / CONVERSIONS[UNITS[k]][units.get(k, UNITS[k])]
        cols[k + "_log"] = -x if k in flip else x
    data = np.column_stack(list(cols.values()))
    with open(path, "w") as fh:
        fh.write(",".join(cols) + "\n")
        np.savetxt(fh, data, delimiter=",", fmt="%.17g")
    return path


def test_csv_degree_kmh_copy(sim_run, tmp_path):
    units = {
        "phi": "deg",
        "delta": "deg",
        "phidot": "deg/s",
        "deltadot": "deg/s",
        "v": "km/h",
        "T_delta": "N cm",
        "psi": "deg",
        "psidot": "deg/s",
        "t": "ms",
    }
    path = _converted_copy(sim_run, tmp_path / "deg.csv", units, time_unit="ms")
    run = from_csv(path, {k: k + "_log" for k in SIGNALS}, units, time="time")
    np.testing.assert_allclose(run.t, sim_run.t, rtol=RTOL, atol=0)
    for k in SIGNALS:
        np.testing.assert_allclose(run.signals[k], sim_run.signals[k], rtol=RTOL, atol=0)
    conv = run.meta["import"]["units"]
    assert conv["phi"] == {"from": "deg", "to": "rad", "factor": math.pi / 180}
    assert conv["v"]["factor"] == 1 / 3.6 and conv["T_delta"]["factor"] == 0.01
    assert conv["t"] == {"from": "ms", "to": "s", "factor": 1e-3}


def test_flip_and_nominal_speed(sim_run, tmp_path):
    path = _converted_copy(sim_run, tmp_path / "left.csv", {}, flip={"phi", "T_delta"})
    cols = {k: k + "_log" for k in SIGNALS if k != "v"}
    run = from_csv(path, cols, time="time", speed=4.5, flip=["phi", "T_delta"])
    for k in cols:
        assert np.array_equal(run.signals[k], sim_run.signals[k]), k
    assert np.all(run.signals["v"] == 4.5) and run.speed == 4.5
    assert run.meta["import"]["flip"] == ["T_delta", "phi"]
    assert run.meta["import"]["speed_source"] == "nominal"
    # without flip the roll angle comes back with the opposite sign: the option is live
    plain = from_csv(path, cols, time="time", speed=4.5)
    assert np.array_equal(plain.signals["phi"], -sim_run.signals["phi"])
    one = from_csv(path, cols, time="time", speed=4.5, flip="phi")  # one name as a string
    assert np.array_equal(one.signals["phi"], sim_run.signals["phi"])


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    choice=st.fixed_dictionaries(
        {k: st.sampled_from(sorted(CONVERSIONS[UNITS[k]])) for k in SIGNALS}
        | {"t": st.sampled_from(["s", "ms"])}
    ),
    flip=st.sets(st.sampled_from(SIGNALS)),
)
def test_random_units_round_trip(sim_run, choice, flip):
    with tempfile.TemporaryDirectory() as d:
        path = _converted_copy(sim_run, Path(d) / "x.csv", choice, flip, time_unit=choice["t"])
        run = from_csv(path, {k: k + "_log" for k in SIGNALS}, choice, time="time", flip=flip)
    np.testing.assert_allclose(run.t, sim_run.t, rtol=RTOL, atol=0)
    for k in SIGNALS:
        np.testing.assert_allclose(run.signals[k], sim_run.signals[k], rtol=RTOL, atol=0)


def test_hdf5_round_trip_arbitrary_paths(sim_run, tmp_path):
    path = tmp_path / "ride.h5"
    where = {k: f"sensors/{'imu' if k.startswith('p') else 'steer'}/{k}_raw" for k in SIGNALS}
    with h5py.File(path, "w") as f:
        f["clock/time"] = sim_run.t.reshape(-1, 1)  # an (N, 1) column is accepted
        for k, p in where.items():
            f[p] = sim_run.signals[k]
        f["notes/text"] = np.bytes_("not a signal")
    run = from_hdf5(path, where, time="clock/time", meta={"rider": "Jason"})
    assert np.array_equal(run.t, sim_run.t)
    for k in SIGNALS:  # float64 datasets: bit for bit
        assert np.array_equal(run.signals[k], sim_run.signals[k]), k
    assert run.meta["rider"] == "Jason" and run.meta["import"]["format"] == "hdf5"
    assert run.meta["import"]["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()


class Frame:
    """A duck-typed table: ``.columns`` and ``frame[name]`` -> list (no pandas)."""

    def __init__(self, data: dict):
        self._data = {k: list(v) for k, v in data.items()}
        self.columns = list(self._data)

    def __getitem__(self, name):
        return self._data[name]


def test_dataframe_duck_typed():
    table = good_table()
    run = from_dataframe(Frame(table), MAP, time="time")
    for k, c in MAP.items():
        assert np.array_equal(run.signals[k], table[c]), k
    assert run.meta["import"]["file"] is None


def test_pandas_dataframe():
    pd = pytest.importorskip("pandas")
    table = good_table()
    run = from_dataframe(Frame(table), MAP, time="time")
    run2 = from_dataframe(pd.DataFrame(table), MAP, time="time")
    assert run2.meta["import"]["sha256"] == run.meta["import"]["sha256"]
    for k in MAP:
        assert np.array_equal(run2.signals[k], run.signals[k]), k


# -- errors ------------------------------------------------------------------------------
def test_missing_column_lists_existing(tmp_path):
    path = write_csv(tmp_path / "log.csv", good_table())
    with pytest.raises(ValueError) as e:
        from_csv(path, {**MAP, "phi": "lean"}, time="time")
    assert_names(str(e.value), str(path), "'lean'", "'roll'", "'torque'")


def test_missing_required_signal_in_mapping(tmp_path):
    path = write_csv(tmp_path / "log.csv", good_table())
    cols = {k: v for k, v in MAP.items() if k != "deltadot"}
    with pytest.raises(ValueError, match=r"required signals \['deltadot'\]"):
        from_csv(path, cols, time="time")


def test_duplicated_column(tmp_path):
    table = good_table()
    header = [c if c != "note" else "roll" for c in table]
    path = write_csv(tmp_path / "dup.csv", table, header=header)
    with pytest.raises(ValueError) as e:
        read(path)
    assert_names(str(e.value), str(path), "row 2", "duplicated", "'roll'")


def test_non_monotonic_time(tmp_path):
    table = good_table()
    table["time"][17] = table["time"][16]
    path = write_csv(tmp_path / "t.csv", table)
    with pytest.raises(ValueError) as e:
        read(path)
    assert_names(str(e.value), str(path), "'time'", f"row {17 + FIRST}", "does not increase")


@pytest.mark.parametrize("excess, ok", [(0.009, True), (0.011, False)])
def test_irregular_time_against_tolerance(tmp_path, excess, ok):
    """One step 0.9 % long passes, 1.1 % long fails (the 1 % tolerance, both ways)."""
    table = good_table()
    table["time"][25:] += excess * DT
    path = write_csv(tmp_path / "j.csv", table)
    if ok:
        assert read(path).n == N
        return
    with pytest.raises(ValueError) as e:
        read(path)
    assert_names(str(e.value), str(path), "'time'", f"row {25 + FIRST}", "irregular")


@pytest.mark.parametrize("text", ["nan", "inf", "-inf"])
def test_nan_or_inf(tmp_path, text):
    path = write_csv(tmp_path / "n.csv", good_table(), cells={(9, "steerrate"): text})
    with pytest.raises(ValueError) as e:
        read(path)
    assert_names(str(e.value), str(path), "'steerrate'", f"row {9 + FIRST}", "non-finite")


def test_nan_in_unmapped_column_is_ignored(tmp_path):
    path = write_csv(tmp_path / "n.csv", good_table(), cells={(9, "note"): "abc"})
    assert read(path).n == N


def test_non_numeric_cell(tmp_path):
    path = write_csv(tmp_path / "s.csv", good_table(), cells={(4, "torque"): "1x"})
    with pytest.raises(ValueError) as e:
        read(path)
    assert_names(str(e.value), str(path), "'torque'", f"row {4 + FIRST}", "'1x'")


def test_empty_cell(tmp_path):
    path = write_csv(tmp_path / "s.csv", good_table(), cells={(0, "roll"): ""})
    with pytest.raises(ValueError) as e:
        read(path)
    assert_names(str(e.value), str(path), "'roll'", f"row {FIRST}", "non-numeric")


def test_ragged_row(tmp_path):
    path = write_csv(tmp_path / "r.csv", good_table(), cells={(6, "note"): "0,0"})
    with pytest.raises(ValueError) as e:
        read(path)
    assert_names(str(e.value), str(path), f"row {6 + FIRST}", "9 fields", "has 8")


@pytest.mark.parametrize("dt, ok", [(DT * 1.005, True), (DT * 1.02, False), (0.001, False)])
def test_dt_mismatch(tmp_path, dt, ok):
    path = write_csv(tmp_path / "d.csv", good_table())
    if ok:
        assert read(path, dt=dt).dt == pytest.approx(DT, rel=1e-12)
        return
    with pytest.raises(ValueError) as e:
        read(path, dt=dt)
    assert_names(str(e.value), str(path), "'time'", f"dt={dt!r}", "sampled every 0.01 s")


def test_constant_signal(tmp_path):
    table = good_table()
    table["steer"][:] = 0.25
    path = write_csv(tmp_path / "c.csv", table)
    with pytest.raises(ValueError) as e:
        read(path)
    assert_names(str(e.value), str(path), "'steer'", "(delta)", "constant")


@pytest.mark.parametrize("swing, ok", [(0.09, True), (0.11, False)])
def test_speed_range(tmp_path, swing, ok):
    """Range 9 % of the mean passes, 11 % fails (the 10 % limit, both ways)."""
    table = good_table()
    table["speed"] = 4.0 * (1 + swing * (np.arange(N) / (N - 1) - 0.5))  # ptp = swing * 4
    path = write_csv(tmp_path / "v.csv", table)
    if ok:
        assert read(path).speed == pytest.approx(4.0, rel=1e-12)
        return
    with pytest.raises(ValueError) as e:
        read(path)
    assert_names(
        str(e.value), str(path), "'speed'", f"row {FIRST}", f"row {N - 1 + FIRST}", "split"
    )


def test_empty_files(tmp_path):
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(ValueError) as e:
        read(empty)
    assert_names(str(e.value), str(empty), "empty")
    header_only = tmp_path / "header.csv"
    header_only.write_text("time,roll,steer,rollrate,steerrate,speed,torque\n")
    with pytest.raises(ValueError) as e:
        read(header_only)
    assert_names(str(e.value), str(header_only), "no data rows")


def test_unreadable_files(tmp_path):
    binary = tmp_path / "photo.csv"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00garbage")
    with pytest.raises(ValueError) as e:
        read(binary)
    assert_names(str(e.value), str(binary), "not UTF-8")
    with pytest.raises(ValueError, match="is a folder"):
        read(tmp_path)
    with pytest.raises(OSError, match="nothere.csv"):
        read(tmp_path / "nothere.csv")
    csv_file = write_csv(tmp_path / "log.csv", good_table())
    with pytest.raises(ValueError) as e:
        from_hdf5(csv_file, MAP, time="time")
    assert_names(str(e.value), str(csv_file), "not a readable HDF5 file")


def test_unknown_unit_names_allowed():
    with pytest.raises(ValueError) as e:
        from_csv("unused.csv", MAP, {"phi": "grad"}, time="time")
    assert_names(str(e.value), "'grad'", "'phi'", "'rad'", "'deg'")
    with pytest.raises(ValueError, match=r"'km/h'.*'mph'"):  # mph is in the table since
        from_csv("unused.csv", MAP, {"v": "furlong/fortnight"}, time="time")  # the unit merge


def test_speed_column_and_nominal_speed_conflict():
    with pytest.raises(ValueError, match="not both"):
        from_csv("unused.csv", MAP, time="time", speed=4.5)
    no_v = {k: c for k, c in MAP.items() if k != "v"}
    with pytest.raises(ValueError, match="positive finite number"):
        from_csv("unused.csv", no_v, time="time", speed=-4.5)
    with pytest.raises(ValueError, match=r"required signals \['v'\]"):
        from_csv("unused.csv", no_v, time="time")


def test_hdf5_errors(tmp_path):
    path = tmp_path / "log.h5"
    table = good_table()
    table["roll"][12] = np.nan
    with h5py.File(path, "w") as f:
        for k, v in table.items():
            f[f"data/{k}"] = v
        f["data/short"] = np.arange(3.0)
    where = {k: f"data/{c}" for k, c in MAP.items()}
    with pytest.raises(ValueError) as e:
        from_hdf5(path, where, time="data/time")
    assert_names(str(e.value), str(path), "'data/roll'", "index 12", "non-finite")
    with pytest.raises(ValueError) as e:
        from_hdf5(path, {**where, "phi": "data/lean"}, time="data/time")
    assert_names(str(e.value), str(path), "'data/lean'", "'data/steer'")
    with pytest.raises(ValueError) as e:
        from_hdf5(path, {**where, "phi": "data/short"}, time="data/time")
    assert_names(str(e.value), str(path), "different lengths", "'data/short': 3")


def test_dataframe_errors():
    table = good_table()
    frame = Frame(table)
    frame._data["torque"][5] = "n/a"
    with pytest.raises(ValueError) as e:
        from_dataframe(frame, MAP, time="time", name="ride.xlsx")
    assert_names(str(e.value), "ride.xlsx", "'torque'", "row 7", "'n/a'")
    frame = Frame(table)
    frame.columns = frame.columns + ["roll"]
    with pytest.raises(ValueError, match=r"duplicated column names \['roll'\]"):
        from_dataframe(frame, MAP, time="time")
    with pytest.raises(ValueError, match="no usable .columns"):
        from_dataframe([1, 2, 3], MAP, time="time")


@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_damaged_csv_never_a_traceback(data):
    """Any truncation, byte flip or insertion of a good file: a Run, a ValueError or OSError."""
    with tempfile.TemporaryDirectory() as d:
        path = write_csv(Path(d) / "log.csv", good_table())
        raw = bytearray(path.read_bytes())
        for _ in range(data.draw(st.integers(1, 4))):
            i = data.draw(st.integers(0, len(raw) - 1))
            op = data.draw(st.sampled_from(["flip", "cut", "insert"]))
            if op == "flip":
                raw[i] = data.draw(st.integers(0, 255))
            elif op == "cut":
                raw = raw[:i]
            else:
                raw[i:i] = data.draw(st.binary(min_size=1, max_size=5))
            if not raw:
                break
        path.write_bytes(bytes(raw))
        try:
            read(path)
        except (ValueError, OSError) as exc:
            assert str(path) in str(exc) and "\n" not in str(exc), str(exc)


def test_semicolon_file(tmp_path):
    path = write_csv(tmp_path / "eu.csv", good_table())
    path.write_text(path.read_text().replace(",", ";"))
    with pytest.raises(ValueError) as e:
        read(path)
    assert_names(str(e.value), str(path), "row 2", "delimiter=';'")
    ref = read(write_csv(tmp_path / "us.csv", good_table()))
    run = read(path, delimiter=";")
    for k in MAP:
        assert np.array_equal(run.signals[k], ref.signals[k]), k


def test_negative_mean_speed(tmp_path):
    table = good_table()
    table["speed"] = -table["speed"]
    path = write_csv(tmp_path / "back.csv", table)
    with pytest.raises(ValueError) as e:
        read(path)
    assert_names(str(e.value), str(path), "'speed'", "not positive")
    assert read(path, flip={"v"}).speed == pytest.approx(4.5, rel=1e-3)  # flip fixes it


def test_reserved_meta_keys(tmp_path):
    path = write_csv(tmp_path / "log.csv", good_table())
    with pytest.raises(ValueError, match=r"\['source'\]"):
        read(path, meta={"source": "mine"})
    assert read(path, meta={"rider": "Jason"}).meta["rider"] == "Jason"


@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_damaged_hdf5_never_a_traceback(data):
    """Flipped bytes in an HDF5 log: a Run (flip in unused bytes), a ValueError or OSError."""
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "log.h5"
        with h5py.File(path, "w") as f:
            for k, v in good_table().items():
                f[f"data/{k}"] = v
        raw = bytearray(path.read_bytes())
        for _ in range(data.draw(st.integers(1, 8))):
            raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
        path.write_bytes(bytes(raw))
        try:
            from_hdf5(path, {k: f"data/{c}" for k, c in MAP.items()}, time="data/time")
        except (ValueError, OSError) as exc:
            assert str(path) in str(exc) and "\n" not in str(exc), str(exc)


def test_dither_column_becomes_the_runs_dither(tmp_path):
    """A logged external excitation maps to Run.dither (not a signal), with unit
    conversion (N cm -> N m: factor 0.01 exactly as CONVERSIONS says); an unknown name is
    refused naming the known ones, dither included."""
    tab = good_table()
    tab["excite"] = 30.0 * np.sin(11 * tab["time"])
    path = write_csv(tmp_path / "d.csv", tab)
    run = from_csv(path, {**MAP, "dither": "excite"}, {"dither": "N cm"}, time="time")
    np.testing.assert_allclose(run.dither, 0.3 * np.sin(11 * tab["time"]), rtol=1e-15, atol=0)
    assert "dither" not in run.signals
    with pytest.raises(ValueError) as exc:
        from_csv(path, {**MAP, "dithr": "excite"}, time="time")
    assert_names(str(exc.value), "dithr", "dither")


# -- provenance and speed stretches -----------------------------------------------------
def test_provenance_path_is_relative_to_the_working_directory(tmp_path, monkeypatch):
    """meta['import']['path'] is the file's path relative to where the command runs (never a
    machine's absolute path), with the SHA-256 of its bytes."""
    import os

    sub = tmp_path / "logs"
    sub.mkdir()
    f = write_csv(sub / "ride.csv", good_table())
    monkeypatch.chdir(tmp_path)
    meta = read(f).meta["import"]
    assert meta["path"] == "logs/ride.csv"
    assert meta["sha256"] == hashlib.sha256(f.read_bytes()).hexdigest()
    monkeypatch.chdir(sub)
    assert read(f).meta["import"]["path"] == "ride.csv"
    assert not os.path.isabs(read(f).meta["import"]["path"])


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(st.tuples(st.floats(0.6, 8.0), st.integers(1200, 3000)), min_size=1, max_size=4),
    st.integers(0, 1000),
)
def test_split_by_speed_finds_the_plateaus(plateaus, seed):
    """Piecewise-constant speeds (0.6-8 m/s plateaus of 12-30 s, 1 cm/s sensor noise) joined
    by 2 s linear ramps: every plateau whose speed differs from its neighbours by more than
    the tolerance comes back as one stretch (within 2.5 s of its true ends: 1 s smoothing
    plus the ramp), with its mean speed to 1 cm/s; the ramps, shorter than min_duration,
    are dropped."""
    from bikeid.dataset.run import Run, split_by_speed

    rng = np.random.default_rng(seed)
    merged = []  # plateaus closer than the tolerance are one stretch
    for v, n in plateaus:
        if merged and abs(merged[-1][0] - v) <= 0.6:
            continue
        merged.append((v, n))
    v_parts, ends, t0 = [], [], 0
    for k, (v, n) in enumerate(merged):
        if k:
            ramp = np.linspace(merged[k - 1][0], v, 200)
            v_parts.append(ramp)
            t0 += 200
        v_parts.append(np.full(n, v))
        ends.append((t0 * 0.01, (t0 + n) * 0.01, v))
        t0 += n
    v = np.concatenate(v_parts)
    n = v.size
    sig = {k: rng.standard_normal(n) for k in CORE}
    sig["v"] = v + 0.01 * rng.standard_normal(n)
    run = Run(t=np.arange(n) * 0.01, signals=sig)
    parts = split_by_speed(run, tolerance=0.25, min_duration=8.0)
    assert len(parts) == len(ends), ([p.speed for p in parts], ends)
    for p, (a, b, speed) in zip(parts, ends, strict=True):
        assert abs(p.speed - speed) < 0.01 and abs(p.t[0] - a) < 2.5 and abs(p.t[-1] - b) < 2.5
        assert p.meta["stretch"][0] == p.t[0]
    assert split_by_speed(run, tolerance=0.25, min_duration=8.0, min_speed=9.0) == []
