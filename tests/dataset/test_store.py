"""HDF5 run storage: bit-identical round trip, atomic writes, clear errors on damaged files.

The reference for every round-trip check is the Run that was written (exact equality of the
float64 bit patterns, so -0.0, subnormals and 17-digit values must survive).  Damage tests
corrupt a written file in a known place and require a ValueError that names the file, the run
group and the problem.
"""

from __future__ import annotations

import json
import os

import h5py
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import bikeid.dataset.store as store
from bikeid.dataset.run import REQUIRED, Run
from bikeid.dataset.store import (
    copy_runs,
    export_csv,
    file_attrs,
    list_runs,
    read_run,
    read_runs,
    write_runs,
)
from bikeid.sim.conventions import UNITS


def make_run(n: int = 300, seed: int = 0, marker: str = "meta-marker") -> Run:
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    names = list(REQUIRED) + ["psi", "psidot", "thetaRdot", "T_phi"]
    # physically plausible values (read_run checks them, sim.conventions.PLAUSIBLE): angles
    # and rates of 0.3 rad(/s), a speed of 4.5 m/s with 0.01 m/s noise like meta["speed"]
    signals = {k: 0.3 * rng.standard_normal(n) for k in names}
    signals["phi"][0] = -0.0
    signals["delta"][1] = 5e-324  # smallest subnormal
    signals["v"] = 4.5 + 0.01 * rng.standard_normal(n)
    truth = {k: 0.3 * rng.standard_normal(n) for k in names}
    truth["v"] = np.full(n, 4.5)
    meta = {
        "speed": 4.5,
        "seed": seed,
        "controller": {"name": "pid", "gains": [-200.0, -500.0, -80.0]},
        "note": marker,
        "unicode": "δ φ ψ",
        "fell_at": None,
    }
    return Run(
        t=t,
        signals=signals,
        truth=truth,
        dither=rng.uniform(-1, 1, n),
        reference=np.sin(t),
        meta=meta,
    )


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return a.shape == b.shape and np.array_equal(a.view(np.uint64), b.view(np.uint64))


def assert_identical(a: Run, b: Run) -> None:
    assert same_bits(a.t, b.t)
    assert list(a.signals) == list(b.signals)
    for k in a.signals:
        assert same_bits(a.signals[k], b.signals[k]), k
    assert (a.truth is None) == (b.truth is None)
    if a.truth is not None:
        assert list(a.truth) == list(b.truth)
        for k in a.truth:
            assert same_bits(a.truth[k], b.truth[k]), k
    for name in ("dither", "reference"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None)
        if x is not None:
            assert same_bits(x, y)
    assert a.meta == b.meta


def test_round_trip_bit_identical(tmp_path):
    runs = [make_run(seed=s) for s in range(3)]
    runs[2].truth = None
    runs[2].dither = None
    path = write_runs(tmp_path / "r.h5", runs, names=["a", "b", "c"], attrs={"sweep": {"x": 1}})
    assert list_runs(path) == ["a", "b", "c"]  # insertion order kept
    assert file_attrs(path) == {"sweep": {"x": 1}}
    for a, b in zip(runs, read_runs(path), strict=True):
        assert_identical(a, b)
    assert_identical(runs[1], read_run(path, "b"))
    with h5py.File(path) as f:  # units attributes follow sim.conventions
        assert f["runs/a/t"].attrs["units"] == "s"
        assert f["runs/a/signals/phidot"].attrs["units"] == UNITS["phidot"] == "rad/s"
        assert f["runs/a/truth/T_delta"].attrs["units"] == "N m"
        assert json.loads(f["runs/a"].attrs["meta"])["speed"] == 4.5


def test_reading_without_the_truth_leaves_everything_else_bit_identical(tmp_path):
    """``read_runs(path, truth=False)`` and ``load_runs(files, LogOptions(truth=False))``
    (what ``validate`` reads with) give the same runs as a full read with ``truth`` None:
    every measured signal, the dither, the reference and the metadata bit for bit; the
    default still reads the truth."""
    from bikeid.dataset.logs import LogOptions, load_runs

    runs = [make_run(seed=s) for s in range(2)]
    path = write_runs(tmp_path / "r.h5", runs, names=["a", "b"])
    for run, lean, full in zip(runs, read_runs(path, truth=False), read_runs(path), strict=True):
        assert lean.truth is None and full.truth is not None
        assert_identical(full, run)
        assert_identical(lean, Run(t=run.t, signals=run.signals, truth=None, dither=run.dither,
                                   reference=run.reference, meta=run.meta))  # fmt: skip
    loaded = load_runs([path], LogOptions(truth=False), note=lambda msg: None)
    assert [r.truth for r in loaded] == [None, None]
    for a, b in zip(loaded, read_runs(path, truth=False), strict=True):
        assert_identical(a, b)
    assert all(r.truth is not None for r in load_runs([path], note=lambda msg: None))


finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
# inside every bound of sim.conventions.PLAUSIBLE (v >= -0.5 m/s, |angles| < pi/2 rad), with
# subnormals and -0.0: the reader refuses values outside (tests/dataset/test_plausibility.py)
plausible = st.floats(min_value=-0.5, max_value=1.5, width=64)


@settings(max_examples=25, deadline=None)
@given(
    data=arrays(np.float64, st.integers(2, 40), elements=plausible),
    meta=st.dictionaries(
        st.text(min_size=1, max_size=8).filter(lambda k: k != "speed"),
        st.one_of(st.none(), st.booleans(), st.integers(-(2**53), 2**53), finite, st.text()),
        max_size=5,
    ),
)
def test_round_trip_any_finite_values(tmp_path_factory, data, meta):
    """Any plausible float64 values and any JSON metadata come back bit for bit."""
    assume(np.ptp(data) > 0)  # a constant run is refused on reading (check_plausible)
    n = data.size
    run = Run(
        t=np.arange(n) * 0.005,
        signals={k: np.roll(data, i) for i, k in enumerate(REQUIRED)},
        meta=meta,
    )
    path = tmp_path_factory.mktemp("h") / "x.h5"
    write_runs(path, [run])
    assert_identical(run, read_runs(path)[0])


def test_interrupted_write_leaves_old_file_intact(tmp_path, monkeypatch):
    path = tmp_path / "r.h5"
    write_runs(path, [make_run(seed=0)])
    before = path.read_bytes()
    calls = []

    def failing(group, name, run):
        calls.append(name)
        if len(calls) == 2:
            raise RuntimeError("simulated crash in the middle of a write")
        return original(group, name, run)

    original = store._write_run
    monkeypatch.setattr(store, "_write_run", failing)
    with pytest.raises(RuntimeError, match="simulated crash"):
        write_runs(path, [make_run(seed=1), make_run(seed=2)])
    assert calls == ["run_0000", "run_0001"]  # the crash happened after a run was written
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["r.h5"]  # no temporary file left behind
    assert_identical(read_runs(path)[0], make_run(seed=0))


@pytest.mark.parametrize("fraction", [0.0, 0.1, 0.5, 0.9, 0.999])
def test_truncated_file_gives_clear_error(tmp_path, fraction):
    path = write_runs(tmp_path / "r.h5", [make_run(seed=0), make_run(seed=1)])
    size = path.stat().st_size
    with open(path, "r+b") as fh:
        fh.truncate(int(size * fraction))
    with pytest.raises(ValueError, match="r.h5") as err:
        read_runs(path)
    assert "truncated" in str(err.value) or "corrupt" in str(err.value)


def _flip(path, offset: int) -> None:
    with open(path, "r+b") as fh:
        fh.seek(offset)
        b = fh.read(1)
        fh.seek(offset)
        fh.write(bytes([b[0] ^ 0xFF]))


def test_flipped_data_byte_is_detected(tmp_path):
    """Fletcher-32 on every chunk: one flipped byte in phi's data names run and dataset."""
    path = write_runs(tmp_path / "r.h5", [make_run(seed=0), make_run(seed=1)], names=["a", "b"])
    with h5py.File(path) as f:
        info = f["runs/b/signals/phi"].id.get_chunk_info(0)
    _flip(path, info.byte_offset + info.size // 2)
    assert_identical(read_run(path, "a"), make_run(seed=0))  # other runs stay readable
    with pytest.raises(ValueError, match=r"run 'b': dataset 'signals/phi'.*corrupt"):
        read_runs(path)


def test_flipped_metadata_byte_is_detected(tmp_path):
    """Object headers carry checksums (HDF5 1.10 format): a flipped byte in the metadata
    attribute must not come back as silently different metadata."""
    path = write_runs(tmp_path / "r.h5", [make_run(seed=0, marker="FINDME-0123456789")])
    offset = path.read_bytes().find(b"FINDME-0123456789")
    assert offset > 0
    _flip(path, offset + 3)
    with pytest.raises(ValueError, match="r.h5.*(corrupt|malformed)"):
        read_runs(path)


def test_deleted_dataset_gives_clear_error(tmp_path):
    path = write_runs(tmp_path / "r.h5", [make_run(seed=0), make_run(seed=1)], names=["a", "b"])
    with h5py.File(path, "a") as f:
        del f["runs/b/signals/delta"]
    with pytest.raises(ValueError, match=r"r.h5: run 'b' is missing required signal.*'delta'"):
        read_runs(path)
    with h5py.File(path, "a") as f:
        del f["runs/a/t"]
    with pytest.raises(ValueError, match=r"run 'a' has no dataset 't'"):
        read_run(path, "a")


def test_unequal_lengths_and_nonfinite_values_are_refused(tmp_path):
    path = write_runs(tmp_path / "r.h5", [make_run(seed=0)], names=["a"])
    with h5py.File(path, "a") as f:
        del f["runs/a/signals/v"]
        f["runs/a/signals"].create_dataset("v", data=np.zeros(299))
    with pytest.raises(ValueError, match=r"run 'a': dataset 'signals/v' has 299 samples but t"):
        read_runs(path)
    with h5py.File(path, "a") as f:
        del f["runs/a/signals/v"]
        bad = np.zeros(300)
        bad[7] = np.nan
        f["runs/a/signals"].create_dataset("v", data=bad)
    with pytest.raises(ValueError, match=r"dataset 'signals/v' holds non-finite"):
        read_runs(path)


def test_foreign_and_future_files_are_refused(tmp_path):
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["x"] = np.zeros(3)
    with pytest.raises(ValueError, match="foreign.h5: not a bikeid run file"):
        read_runs(foreign)
    path = write_runs(tmp_path / "r.h5", [make_run()])
    with h5py.File(path, "a") as f:
        f.attrs["format_version"] = 99
    with pytest.raises(ValueError, match="version 99 is not supported"):
        list_runs(path)
    text = tmp_path / "t.h5"
    text.write_text("not hdf5 at all\n" * 100)
    with pytest.raises(ValueError, match="t.h5: not a readable HDF5 file"):
        read_runs(text)
    with pytest.raises(FileNotFoundError):
        read_runs(tmp_path / "missing.h5")


def test_bad_names_are_refused(tmp_path):
    with pytest.raises(ValueError, match="duplicate run names"):
        write_runs(tmp_path / "r.h5", [make_run(), make_run()], names=["a", "a"])
    with pytest.raises(ValueError, match="without '/'"):
        write_runs(tmp_path / "r.h5", [make_run()], names=["a/b"])
    assert not (tmp_path / "r.h5").exists()


def test_copy_runs_equals_direct_write(tmp_path):
    parts = []
    for s in range(3):
        parts.append(write_runs(tmp_path / f"p{s}.h5", [make_run(seed=s)], names=[f"r{s}"]))
    out = copy_runs(tmp_path / "all.h5", [(p, f"r{s}") for s, p in enumerate(parts)])
    assert list_runs(out) == ["r0", "r1", "r2"]
    for s, run in enumerate(read_runs(out)):
        assert_identical(run, make_run(seed=s))


def test_csv_export_round_trips_values_and_units(tmp_path):
    run = make_run(n=50)
    path = export_csv(run, tmp_path / "run.csv")
    lines = path.read_text().splitlines()
    assert lines[0].startswith("# bikeid run: ")
    assert json.loads(lines[0][len("# bikeid run: ") :]) == run.meta
    header = lines[1].split(",")
    assert header[:3] == ["t [s]", "v [m/s]", "phi [rad]"]
    assert "true_deltadot [rad/s]" in header and "T_delta [N m]" in header
    data = np.loadtxt(path, delimiter=",", skiprows=2)
    assert data.shape == (50, len(header))
    cols = {h.split(" [")[0]: data[:, i] for i, h in enumerate(header)}
    assert same_bits(cols["t"], run.t)
    for k in run.signals:
        assert same_bits(cols[k], run.signals[k]), k  # %.17g round-trips float64 exactly
    for k in run.truth:
        assert same_bits(cols[f"true_{k}"], run.truth[k]), k
    assert same_bits(cols["dither"], run.dither)
