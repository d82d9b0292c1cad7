"""Loader for the TU Delft steer-by-wire treadmill logs (``tudelft-sbw``).

Format (see the data README): gzip CSV with a header, one row per 10 ms control loop,
no time column, so t = i * 0.01 s.  Units are SI (rad, rad/s, N m, m/s).

What the loader does, and why
------------------------------
- **Time base**: t = i * 0.01 s from the first row of the file (row indices of
  ``eigen/segments.csv`` refer to the same numbering).
- **Free-decay windows**: the rows of ``eigen/segments.csv`` (transcribed from the
  source's analysis) where it lists the log; for any other eigen log (a new run, a
  fetched folder without the segments file) :func:`detect_decays` finds them from the
  roll rate.
- **Empty sil_command rows**: some logs open with rows whose ``sil_command`` field is
  empty (controller not running yet).  Those leading rows are cut; an empty field later
  in the file is a malformed file.
- **Spikes** in ``fork_rate``, ``x_acceleration`` and ``y_acceleration``: a sample is a
  spike when its distance from the 5-sample running median exceeds
  ``SPIKE_K`` = 8 times the robust scale (1.4826 * median absolute deviation of that
  distance over the whole file) *and* ``SPIKE_FLOOR`` (0.5 rad/s, 5 m/s^2).  Spikes
  are replaced by linear interpolation between good neighbours; the count goes to
  ``meta['spikes']``.  (fork_rate is the encoder difference, quantized at 0.077 rad/s;
  its spikes are isolated one-sample jumps the steer angle does not follow.)
- **Speed**: the ``speed`` column is the rear-wheel encoder (500-sample moving
  average), which per the source's calibration reads ``1.066 * treadmill - 0.128``.
  ``signals['v']`` is the logged sensor speed (what the controller used);
  ``meta['speed']`` is the treadmill speed from the calibration applied to the median of
  the settled part of the file; ``meta['speed_sensor']`` the settled sensor median.
  The plateau is the most populated 0.05 m/s bin of the speed histogram; samples more
  than 5 % off it belong to a ramp.  ``meta['ramp_end_index']`` is the first settled
  row, ``meta['settled_end_index']`` one past the last one (a run-down at the end);
  the Run keeps all rows so that segment indices stay valid.
- **Signals**: phi = lean_angle, phidot = lean_rate, delta = fork_angle,
  deltadot = fork_rate, v = speed, T_delta = command_fork (total steer-motor command,
  the plant input); extras ``sil_command``, ``hand_torque``, ``hand_angle``,
  ``command_hand``, ``x_acceleration``, ``y_acceleration`` and ``T_ext`` =
  command_fork - sil_command (the part of the steer torque that is not the balance
  controller: the relayed handlebar torque in the Bode runs, zero in the eigen runs).

Sign conventions (checked against the physics, see ``docs/measured.md``)
-----------------------------------------------------------------------
``sil_command`` equals ``+2 (6.5 - speed) lean_rate`` to 1e-9 (correlation) in every
file.  With roll and steer positive to the right (Meijaard 2007) a steer torque *in
the direction of the roll rate* is the stabilizing steer-into-lean law: the Whipple
model of this bicycle closed with ``T = +K (V - v) phidot`` is stable at 1.5-4.5 m/s,
with ``-K`` it is unstable.  The bicycle stayed up in all runs, and the free decays
show steer and roll of the same sign (steer into the lean), as the model predicts.  So
roll, roll rate, steer and steer torque of the logs share the benchmark's signs.  A
mirror image (all four flipped together) leaves the dynamics unchanged, so physics
alone cannot fix the absolute direction; the relative signs are what the model needs.
"""

from __future__ import annotations

import csv
import gzip
import hashlib
import io
import json
import os
import tempfile
import urllib.request
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bikeid.dataset.run import Run

__all__ = [
    "CAMPAIGN",
    "COLUMNS",
    "DT",
    "SPEED_CALIBRATION",
    "UPSTREAM_COMMIT",
    "Segment",
    "data_dir",
    "despike",
    "detect_decays",
    "fetch",
    "find_logs",
    "iter_decays",
    "load_log",
    "read_segments",
    "treadmill_speed",
]

DT = 0.01  # s, one control loop
COLUMNS = (
    "sil_command", "speed", "lean_angle", "lean_rate", "hand_angle", "fork_angle",
    "fork_rate", "lean_torque", "hand_torque", "x_acceleration", "y_acceleration",
    "command_fork", "command_hand",
)  # fmt: skip
#: sensor = a * treadmill + b (source calibration, data README)
SPEED_CALIBRATION = (1.066, -0.128)
SPIKE_K = 8.0
SPIKE_FLOOR = {"fork_rate": 0.5, "x_acceleration": 5.0, "y_acceleration": 5.0}
DATASET = "tudelft-sbw"
UPSTREAM_REPO = "mechmotum/sbw_bicycle_with_model_matching"
UPSTREAM_COMMIT = "2e7bb2451997fa821b5e90bf6ca5d2acbb7948a8"
UPSTREAM_URL = "https://raw.githubusercontent.com/{repo}/{commit}/teensy/logs/{path}"
#: pinned files: local path under tudelft-sbw/ -> upstream path under teensy/logs/
PINNED = {
    **{
        f"eigen/eigen_normal_sil6.5n2_{k}kph.log.gz": f"eigen_normal_sil6.5n2_{k}kph.log"
        for k in ("5.4", "9", "12.6", "16.2")
    },
    **{
        f"bode-4mps/bode_normal_4mps_{f}Hz.log.gz": f"bodetest-4m_per_s/bode_normal_4mps_{f}Hz.log"
        for f in (
            "1.0",
            "1.1",
            "1.2",
            "1.3",
            "1.4",
            "1.5",
            "1.6",
            "1.7",
            "1.8",
            "1.9",
            "2.05",
            "2.2",
            "2.4",
            "2.6",
            "2.8",
            "3.0",
        )  # fmt: skip
    },
}

#: the campaign's other free-decay runs with the same controller (2, 3, 4, 5 m/s), listed
#: in the transcribed segments.csv; ``bikeid data fetch --all-speeds``.  Their upstream
#: paths follow the pinned eigen logs' pattern (not verified from the offline build
#: machine; a missing file fails with the URL and writes nothing for it).
CAMPAIGN = {
    f"eigen/eigen_normal_sil6.5n2_{k}kph.log.gz": f"eigen_normal_sil6.5n2_{k}kph.log"
    for k in ("7.2", "10.8", "14.4", "18")
}


def treadmill_speed(sensor: np.ndarray | float) -> np.ndarray | float:
    """Treadmill speed [m/s] from the rear-wheel sensor speed (inverse calibration)."""
    a, b = SPEED_CALIBRATION
    return (np.asarray(sensor) - b) / a


def data_dir(path: str | os.PathLike | None = None) -> Path:
    """The ``tudelft-sbw`` folder: from ``path`` (``--data``), else ``$BIKEID_DATA``.

    Either may name the folder itself or its parent (CI: ``BIKEID_DATA=../shared/data``).
    """
    src = path if path is not None else os.environ.get("BIKEID_DATA")
    if not src:
        raise ValueError(
            "no data directory: pass --data DIR or set BIKEID_DATA to the folder that "
            f"contains {DATASET}/ (get the files with 'bikeid data fetch')"
        )
    root = Path(src).expanduser()
    for cand in (root / DATASET, root):
        if cand.is_dir() and (any(cand.glob("*/*.log*")) or any(cand.glob("*.log*"))):
            return cand
    raise ValueError(f"data directory {root} holds no {DATASET} logs (*.log or *.log.gz)")


def find_logs(root: str | os.PathLike, kind: str | None = None) -> list[Path]:
    """All ``*.log``/``*.log.gz`` files under ``root`` (optionally whose name starts with kind)."""
    files = sorted(
        p for p in Path(root).rglob("*") if p.is_file() and p.name.endswith((".log", ".log.gz"))
    )
    if kind:
        files = [p for p in files if p.name.startswith(kind)]
    return files


def _read_text(path: Path) -> str:
    try:
        if path.name.endswith(".gz"):
            with gzip.open(path, "rt", newline="") as fh:
                return fh.read()
        return path.read_text()
    except (EOFError, gzip.BadGzipFile, zlib.error, UnicodeDecodeError) as exc:
        raise ValueError(
            f"{path.name}: corrupt or truncated file ({exc}); fetch it again"
        ) from None


def despike(x: np.ndarray, floor: float, k: float = SPIKE_K) -> tuple[np.ndarray, int]:
    """Replace isolated spikes by interpolation (detector: see module docstring)."""
    x = np.asarray(x, dtype=float)
    if x.size < 5:
        return x.copy(), 0
    pad = np.pad(x, 2, mode="edge")
    med = np.median(np.lib.stride_tricks.sliding_window_view(pad, 5), axis=1)
    dev = np.abs(x - med)
    scale = 1.4826 * np.median(dev)
    bad = dev > max(k * scale, floor)
    nbad = int(bad.sum())
    if nbad == 0 or nbad == x.size:
        return x.copy(), 0
    out = x.copy()
    idx = np.arange(x.size)
    out[bad] = np.interp(idx[bad], idx[~bad], x[~bad])
    return out, nbad


def load_log(path: str | os.PathLike) -> Run:
    """Read one steer-by-wire log into a :class:`dataset.run.Run` (see module docstring).

    Raises ValueError naming the file and the problem for missing columns,
    non-numeric fields, a truncated gzip stream or too few rows.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"log file {path} does not exist")
    text = _read_text(path)
    reader = csv.reader(io.StringIO(text))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise ValueError(f"{path.name}: empty file, expected a CSV header") from None
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise ValueError(f"{path.name}: missing columns {missing}; expected {list(COLUMNS)}")
    col = {c: header.index(c) for c in COLUMNS}
    rows = [r for r in reader if r and any(f.strip() for f in r)]
    if len(rows) < 10:
        raise ValueError(f"{path.name}: only {len(rows)} data rows; need at least 10")
    # leading rows with an empty sil_command: controller not yet running
    first = 0
    while first < len(rows) and (
        len(rows[first]) <= col["sil_command"] or not rows[first][col["sil_command"]].strip()
    ):
        first += 1
    if first == len(rows):
        raise ValueError(f"{path.name}: sil_command is empty in every row")
    data = np.empty((len(rows) - first, len(COLUMNS)))
    for i, r in enumerate(rows[first:]):
        if len(r) != len(header):
            raise ValueError(
                f"{path.name}: row {first + i + 2} has {len(r)} fields, header has "
                f"{len(header)} (truncated or malformed file)"
            )
        for j, c in enumerate(COLUMNS):
            try:
                data[i, j] = float(r[col[c]])
            except ValueError:
                raise ValueError(
                    f"{path.name}: row {first + i + 2}, column {c!r}: non-numeric value "
                    f"{r[col[c]]!r}"
                ) from None
    if not np.all(np.isfinite(data)):
        raise ValueError(f"{path.name}: non-finite values in the data")
    raw = {c: data[:, j] for j, c in enumerate(COLUMNS)}
    spikes = {}
    for c, floor in SPIKE_FLOOR.items():
        raw[c], spikes[c] = despike(raw[c], floor)
    n = data.shape[0]
    t = (first + np.arange(n)) * DT
    v = raw["speed"]
    settled, ramp_end, run_end = _settled_speed(v)
    signals = {
        "phi": raw["lean_angle"],
        "phidot": raw["lean_rate"],
        "delta": raw["fork_angle"],
        "deltadot": raw["fork_rate"],
        "v": v,
        "T_delta": raw["command_fork"],
        "T_ext": raw["command_fork"] - raw["sil_command"],
        **{
            c: raw[c]
            for c in (
                "sil_command",
                "hand_torque",
                "hand_angle",
                "command_hand",
                "x_acceleration",
                "y_acceleration",
            )  # fmt: skip
        },
    }
    meta = {
        "source": "measured",
        "dataset": DATASET,
        "file": path.name,
        "speed": float(treadmill_speed(settled)),
        "speed_sensor": settled,
        "first_index": first,
        "ramp_end_index": first + ramp_end,
        "settled_end_index": first + run_end,
        "spikes": spikes,
        "controller": {"law": "steer-into-lean", "T": "K (V - speed) phidot", "K": 2.0, "V": 6.5},
        "bicycle": "steer-by-wire",
        "dt": DT,
    }
    return Run(t=t, signals=signals, meta=meta)


def _settled_speed(v: np.ndarray) -> tuple[float, int, int]:
    """Treadmill plateau of the sensor speed: (median, first index, end index).

    The plateau is the most populated 0.05 m/s bin of the speed histogram; samples
    within 5 % of it are settled.  Returns the median of the settled samples, the first
    settled index (the end of a start-up ramp) and one past the last settled index
    (a run-down at the end is cut there).
    """
    edges = np.arange(np.floor(v.min() / 0.05) * 0.05, v.max() + 0.1, 0.05)
    hist, edges = np.histogram(v, bins=edges)
    mode = 0.5 * (edges[np.argmax(hist)] + edges[np.argmax(hist) + 1])
    ok = np.abs(v - mode) <= 0.05 * max(abs(mode), 0.1)
    settled = float(np.median(v[ok]))
    idx = np.flatnonzero(ok)
    return settled, int(idx[0]), int(idx[-1] + 1)


@dataclass(frozen=True)
class Segment:
    """A free-decay window: rows start..end-1 of ``file`` (indices in file rows)."""

    file: str
    speed: float
    start: int
    end: int


def read_segments(path: str | os.PathLike, available: set[str] | None = None) -> list[Segment]:
    """Rows of ``segments.csv``; rows whose file is not in ``available`` are skipped."""
    path = Path(path)
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        need = {"file", "speed_mps", "start_idx", "end_idx"}
        if not reader.fieldnames or not need <= set(reader.fieldnames):
            raise ValueError(f"{path.name}: need columns {sorted(need)}")
        out = []
        for i, r in enumerate(reader):
            try:
                seg = Segment(
                    r["file"].strip(), float(r["speed_mps"]), int(r["start_idx"]), int(r["end_idx"])
                )
            except (TypeError, ValueError):
                raise ValueError(f"{path.name}: row {i + 2} is malformed: {r}") from None
            if seg.end <= seg.start + 10:
                raise ValueError(f"{path.name}: row {i + 2} has end <= start + 10")
            if available is None or seg.file in available:
                out.append(seg)
    return out


#: free-decay detector settings (:func:`detect_decays`)
DECAY_LENGTH = 1.0  # s, window length (the transcribed windows are 1 s)
DECAY_K = 6.0  # onset threshold in robust standard deviations of the roll rate
DECAY_MIN_PEAK = 0.2  # rad/s, lower bound of the onset threshold
DECAY_QUIET = 0.35  # max |roll rate| in the second before the push, relative to the peak
DECAY_RATIO = 0.5  # max |roll rate| over the window's second half, relative to the peak


def detect_decays(run: Run, length: float = DECAY_LENGTH) -> list[Segment]:
    """Free decays in an eigen log found from the roll rate alone (no segments file).

    A push shows as |roll rate| rising above max(6 sigma, 0.2 rad/s), sigma the robust
    (1.4826 MAD) scale of the whole log's roll rate.  The window starts at the extreme of
    that first lobe (|roll rate| > half the threshold with the same sign; the hand has
    left: from there on the motion is the loop's own) and lasts ``length`` s.  It is kept
    only if it is a clean decay from rest: within the settled-speed part of the log; in
    the second before the push (less its last 0.15 s) |roll rate| stayed below 0.35 x the
    peak; over the window's second half it stays below 0.5 x the peak; and it never
    exceeds 1.1 x the peak (no second push).  The next search starts after the window.  On the four
    ``eigen_normal`` logs this finds every window of the transcribed ``segments.csv``
    whose push clears the threshold, at the same start to a few samples, plus the
    pushes the source's analysis did not use (tests/test_measured.py, docs/measured.md);
    those fit the model worse, so the curated list is the default where it exists.
    """
    pr = np.asarray(run.signals["phidot"], dtype=float)
    first = int(run.meta.get("first_index", 0))
    lo = int(run.meta.get("ramp_end_index", first)) - first
    hi = int(run.meta.get("settled_end_index", first + pr.size)) - first
    m = int(round(length / DT))
    if m < 20:
        raise ValueError(f"decay window length {length} s is too short (need >= 0.2 s)")
    sigma = 1.4826 * float(np.median(np.abs(pr - np.median(pr))))
    thr = max(DECAY_K * sigma, DECAY_MIN_PEAK)
    pre, gap = int(round(1.0 / DT)), int(round(0.15 / DT))
    speed = float(run.meta.get("speed", np.nan))
    out: list[Segment] = []
    i = max(lo, pre)
    while i < hi - m:
        if abs(pr[i]) <= thr:
            i += 1
            continue
        sgn, k = np.sign(pr[i]), i
        while k + 1 < hi and sgn * pr[k + 1] > 0.5 * thr:  # the push's first lobe
            k += 1
        j = i + int(np.argmax(sgn * pr[i : k + 1]))
        peak = abs(pr[j])
        win = np.abs(pr[j : j + m])
        clean = (
            j + m <= hi
            and np.max(np.abs(pr[i - pre : i - gap])) < DECAY_QUIET * peak
            and np.max(win[m // 2 :]) < DECAY_RATIO * peak
            and np.max(win) <= 1.1 * peak
        )
        if clean:
            out.append(Segment(run.meta.get("file", "?"), speed, first + j, first + j + m))
        i = j + m
    return out


def iter_decays(
    root: str | os.PathLike, source: str = "listed"
) -> Iterator[tuple[Run, list[Segment]]]:
    """(run, its free-decay windows) for every eigen log (name starting ``eigen``) under root.

    ``source="listed"``: the windows of ``segments.csv`` (in the log's folder) for the logs
    it lists, :func:`detect_decays` for the others, so a new log of this format needs no
    segments file.  ``source="detected"``: :func:`detect_decays` for every log.
    """
    if source not in ("listed", "detected"):
        raise ValueError(f"unknown decay source {source!r}; use 'listed' or 'detected'")
    lists: dict[Path, list[Segment]] = {}  # segments.csv of each folder, read once
    for path in find_logs(root, "eigen"):
        sf = path.parent / "segments.csv"
        if source == "listed" and sf.is_file() and sf not in lists:
            lists[sf] = read_segments(sf)
        run = load_log(path)
        segs = [sg for sg in lists.get(sf, []) if sg.file == path.name] or detect_decays(run)
        if segs:
            yield run, segs


# -- download -----------------------------------------------------------------------------
def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def fetch(
    dest: str | os.PathLike,
    commit: str = UPSTREAM_COMMIT,
    opener: Callable[[str], bytes] | None = None,
    url_pattern: str = UPSTREAM_URL,
    files: dict[str, str] | None = None,
) -> dict[str, str]:
    """Download the pinned logs into ``dest/tudelft-sbw/`` (gzip), atomically.

    Each file is fetched from ``url_pattern`` (upstream raw GitHub at the pinned
    commit), gzip-compressed and written via a temporary file + rename.  The SHA-256
    of the upstream bytes is recorded in ``checksums.json`` on first download and
    checked on every later one (a mismatch raises ValueError and writes nothing).
    ``segments.csv`` is not an upstream file (it was transcribed from the source's
    analysis script) and is not fetched: in a fetched folder the decay windows are
    detected (:func:`detect_decays`).  Returns {local path: sha256}.
    """
    opener = opener or _urlopen
    files = PINNED if files is None else files
    root = Path(dest) / DATASET
    root.mkdir(parents=True, exist_ok=True)
    sums_path = root / "checksums.json"
    sums = json.loads(sums_path.read_text()) if sums_path.exists() else {}
    out = {}
    for local, remote in files.items():
        url = url_pattern.format(repo=UPSTREAM_REPO, commit=commit, path=remote)
        data = opener(url)
        digest = _sha256(data)
        if local in sums and sums[local] != digest:
            raise ValueError(
                f"checksum mismatch for {local}: recorded {sums[local][:12]}..., got "
                f"{digest[:12]}...; delete {sums_path} only if the upstream file really changed"
            )
        target = root / local
        target.parent.mkdir(parents=True, exist_ok=True)
        payload = gzip.compress(data, mtime=0) if local.endswith(".gz") else data
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as fh:
                fh.write(payload)
            os.replace(tmp, target)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        sums[local] = digest
        out[local] = digest
    text = json.dumps(sums, indent=2, sort_keys=True) + "\n"
    fd, tmp = tempfile.mkstemp(dir=root, prefix=".checksums.", suffix=".tmp")
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
    os.replace(tmp, sums_path)
    return out


def _urlopen(url: str) -> bytes:  # pragma: no cover - needs network
    try:
        with urllib.request.urlopen(url, timeout=60) as resp:
            return resp.read()
    except OSError as exc:  # URLError, HTTPError and timeouts are OSErrors
        reason = getattr(exc, "reason", exc)
        raise ValueError(
            f"could not download {url}: {reason}; check the network connection, or copy the "
            "data folder by hand and point --data / BIKEID_DATA at it"
        ) from None
