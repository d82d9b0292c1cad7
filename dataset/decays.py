"""Free-decay windows of the eigen logs: the listed rows of ``segments.csv`` or detected.

- **Listed**: the rows of ``eigen/segments.csv`` (transcribed from the source's analysis)
  where it lists the log (:func:`read_segments`).
- **Detected**: for any other eigen log (a new run, a fetched folder without the segments
  file) :func:`detect_decays` finds them from the roll rate; a window lasts 1 s, or up to
  3 s for a decay that needs longer to halve (:data:`DECAY_MAX_LENGTH`).

:func:`iter_decays` gives each eigen log with its windows; :func:`load_decays` turns them
into :class:`bikeid.dataset.windows.Window` objects, optionally only near some speeds.
Row indices are those of the log file (t = index * 0.01 s, :mod:`bikeid.dataset.sbw_logs`).
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from bikeid.dataset.run import Run
from bikeid.dataset.sbw_logs import data_dir, find_logs, load_log
from bikeid.dataset.windows import Window, decay_windows
from bikeid.sim.errors import InputError

__all__ = [
    "DECAY_K",
    "DECAY_LENGTH",
    "DECAY_LULL",
    "DECAY_MAX_LENGTH",
    "DECAY_MIN_PEAK",
    "DECAY_QUIET",
    "DECAY_RATIO",
    "DECAY_REGROW",
    "MIN_FIT_DECAYS",
    "Segment",
    "decays_from_runs",
    "detect_decays",
    "iter_decays",
    "load_decays",
    "read_segments",
    "slowest_decay_rate",
    "steer_by_wire_logs",
]


@dataclass(frozen=True)
class Segment:
    """A free-decay window: rows start..end-1 of ``file`` (indices in file rows).

    Attributes
    ----------
    file : str
        Log file name (no folder), e.g. ``eigen_normal_...log``.
    speed : float
        Treadmill speed of the log [m/s] (NaN when a detected window's run has none).
    start : int
        First row of the window (file row index; t = row * 0.01 s).
    end : int
        One past the last row (file row index).
    """

    file: str
    speed: float
    start: int
    end: int


def read_segments(path: str | os.PathLike, available: set[str] | None = None) -> list[Segment]:
    """Rows of ``segments.csv``; rows whose file is not in ``available`` are skipped.

    Parameters
    ----------
    path : str or path-like
        The CSV (columns file, speed_mps, start_idx, end_idx).
    available : set of str, optional
        File names to keep.

    Returns
    -------
    list of Segment
        One per kept row, in file order.

    Raises
    ------
    ValueError
        If a column is missing, a row does not parse (the message gives the file's line
        number and the row), or a row has ``end_idx <= start_idx + 10``.
    OSError
        If the file cannot be read.
    """
    path = Path(path)
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        try:
            return _segments(path, reader, available)
        except csv.Error as exc:  # e.g. a field over csv.field_size_limit() characters
            raise ValueError(
                f"{path.name}: line {reader.line_num} is not valid CSV ({exc}); restore the file"
            ) from None


def _segments(path: Path, reader: csv.DictReader, available: set[str] | None) -> list[Segment]:
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
            raise ValueError(
                f"{path.name}: row {i + 2} is malformed ({str(r)[:80]}); need file, "
                "speed_mps, start_idx, end_idx"
            ) from None
        if not (math.isfinite(seg.speed) and seg.speed > 0):
            raise ValueError(f"{path.name}: row {i + 2}: speed_mps {seg.speed} must be > 0")
        if seg.end <= seg.start + 10:
            raise ValueError(f"{path.name}: row {i + 2} has end <= start + 10")
        if available is None or seg.file in available:
            out.append(seg)
    return out


#: free-decay detector settings (:func:`detect_decays`)
DECAY_LENGTH = 1.0  # s, shortest window (the transcribed windows are 1 s)
DECAY_MAX_LENGTH = 3.0  # s, longest window: a slow decay may take this long to halve
DECAY_K = 6.0  # onset threshold in robust standard deviations of the roll rate
DECAY_MIN_PEAK = 0.2  # rad/s, lower bound of the onset threshold
DECAY_QUIET = 0.35  # max |roll rate| in the second before the push, relative to the peak
DECAY_RATIO = 0.5  # max |roll rate| over the window's second half, relative to the peak
DECAY_REGROW = 1.1  # a lobe above this x the lobes before it is a push (not the same motion)
DECAY_LULL = 0.4  # s, a lobe above the onset threshold after this long calm is a second push
#: The window starts this fraction of the push's rise time after the roll-rate extreme: a push
#: that lasts D s (a half-sine) still acts for about 0.25 D after the extreme, a third of its
#: rise (independent linear generator, pulses of 0.1-0.4 s: the extreme 0-0.07 s before the
#: pulse's end); 0.5 leaves a margin.
DECAY_SETTLE = 0.5
#: The push's onset: the last sample before the extreme with |roll rate| below this x peak.
DECAY_ONSET = 0.1
#: Longest settling delay [s] (a push rising for longer is a lean, not a hand's push).
DECAY_MAX_SETTLE = 0.2
#: The push's response (the next lobe, of the other sign) may exceed the push's own lobe by
#: this factor and still be the loop's free motion (a lightly damped loop swings back past
#: the forced lobe: 1.1-1.36 x on the closure generator's 20-30 ms input-delay logs, seeds
#: 32 and 38); a larger one is a second push.
DECAY_RESPONSE_MAX = 1.5


def slowest_decay_rate(max_length: float = DECAY_MAX_LENGTH) -> float:
    """The slowest exponential envelope :func:`detect_decays` keeps, -2 ln(1/ratio) / max_length.

    A window of length L is kept when the second half stays below :data:`DECAY_RATIO` x the
    peak; for an envelope e^{sigma t} whose lobes fall at L/2 that is e^{sigma L / 2} <
    ratio, so with L at most ``max_length`` the envelope must decay faster than this rate.

    Parameters
    ----------
    max_length : float, optional
        Longest window [s] (default :data:`DECAY_MAX_LENGTH`, 3 s).

    Returns
    -------
    float
        The rate sigma [1/s] (negative): -0.462 1/s for 3 s and the ratio 0.5.

    Raises
    ------
    ValueError
        If ``max_length`` is not a positive number.
    """
    if not (isinstance(max_length, (int, float)) and max_length > 0):
        raise ValueError(f"max_length must be a positive number of seconds, got {max_length!r}")
    return 2.0 * math.log(DECAY_RATIO) / float(max_length)


def detect_decays(
    run: Run,
    length: float = DECAY_LENGTH,
    rejected: list | None = None,
    max_length: float | None = DECAY_MAX_LENGTH,
) -> list[Segment]:
    """Free decays in an eigen log found from the roll rate alone (no segments file).

    A push shows as |roll rate| rising above max(6 sigma, 0.2 rad/s), sigma the robust
    (1.4826 MAD) scale of the roll rate over the settled-speed part of the log (the rows
    the windows may come from; the whole log when it has no start-up ramp).  The window
    starts after the extreme of that first lobe (|roll rate| > half the threshold with the
    same sign) by :data:`DECAY_SETTLE` (0.5) x the push's rise time, from its onset (the last
    sample with |roll rate| below :data:`DECAY_ONSET` x peak) to the extreme, at most
    :data:`DECAY_MAX_SETTLE` (0.2 s): the extreme is where the push's roll moment has fallen
    to the loop's, not where the hand has left (a half-sine push of D s still acts for about
    0.25 D after it), and a window that starts while the push still acts gives the push's
    tail to the effects (on the closure generator, an input delay fitted as an actuator lag).
    From the window's start on the motion is the loop's own.  A lobe
    no larger than 1.1 x the largest |roll rate| of the second before it (less its last
    0.15 s) is the motion before going on, not a push: it is skipped, neither kept nor
    counted.  A push is kept only if it is a clean decay from rest: within the
    settled-speed part of the log; in the second before the push (less its last 0.15 s)
    |roll rate| stayed below 0.35 x the peak; it decays: over the window's second half
    |roll rate| stays below 0.5 x the peak; and it never exceeds 1.1 x the peak.  The peak
    is the push's own, or its response's (the next lobe, of the other sign) when that is
    larger but at most :data:`DECAY_RESPONSE_MAX` (1.5) x the push's: a lightly damped loop
    swings back past the forced lobe.

    **The window follows the decay.**  Its length L is the shortest from ``length`` (1 s)
    up to ``max_length`` (3 s) whose second half stays below 0.5 x the peak: a decay that
    has halved within 0.5 s keeps a 1 s window, a slower one a window about twice its
    halving time, so at least half of every window shows the decayed motion.  The slowest
    envelope e^{sigma t} kept has sigma = 2 ln 0.5 / max_length (-0.46 1/s for 3 s,
    :func:`slowest_decay_rate`; a fixed 1 s window needs sigma < -1.39 1/s, which refused
    the weave of a loop with a 10-30 ms input delay, -0.5 to -1.6 1/s).  A window longer
    than ``length`` never runs past the settled speed and ends before the next push.  Lobes
    are the excursions of the roll rate beyond -+ half the onset threshold; a free decay's
    lobes each rise and fall once and shrink.  A second push is a lobe rising above the
    onset threshold after more than 0.4 s within that band (the decay's oscillation crosses
    it in at most 1.05 / omega s, 0.35 s at 3 rad/s), a lobe rising again above 1.1 x its
    extreme after falling below half of it, or, after the push's own lobe and the next
    (its response, which may be the larger), a lobe above 1.1 x every lobe since the push's
    own.  A window that has not halved before a second push is rejected.  The search for
    the next push starts after the window; after a rejected one, after ``max_length`` or at
    that second push.
    With ``max_length`` None (or equal to ``length``) every window is ``length`` long.

    On the four ``eigen_normal`` logs this finds every window of the transcribed
    ``segments.csv`` whose push clears the threshold, starting its settling delay after
    the transcribed start (which is at the extreme; 6-20 samples, the hand pushes rising for
    0.12-0.4 s) and with the same 1 s length, plus the pushes the source's analysis did not use
    (tests/ident/effects/test_pipeline.py, docs/measured.md); those fit the model worse,
    so the curated list is the default where it exists.

    Any log of :class:`~bikeid.dataset.run.Run` works (the steer-by-wire logs or a user's
    CSV/HDF5 log): the sample period is the run's own (:attr:`Run.dt`).

    Parameters
    ----------
    run : Run
        A log with pushes and free decays (roll rate ``phidot`` [rad/s]).
    length : float, optional
        Shortest window length [s] (default :data:`DECAY_LENGTH` = 1 s).
    rejected : list, optional
        When given, each push that cleared the threshold but was not kept is appended as
        ``(row, reason)`` (file row index of its peak, not of the window's start, which is
        the settling delay later; a short reason: not at rest in the
        second before it; does not decay within the longest window; rises above 1.1 x its
        peak; a second push before it decayed; past the end of the settled speed).
    max_length : float or None, optional
        Longest window length [s] (default :data:`DECAY_MAX_LENGTH` = 3 s; None:
        ``length``).

    Returns
    -------
    list of Segment
        The clean decays in time order, rows in file row indices, ``speed`` the run's
        treadmill speed [m/s] (NaN if the run has none); ``length`` to ``max_length`` long.

    Raises
    ------
    ValueError
        If ``length`` is shorter than 20 samples, or ``max_length`` shorter than
        ``length``.
    """
    pr = np.asarray(run.signals["phidot"], dtype=float)
    dt = float(run.meta.get("dt") or run.dt)
    first = int(run.meta.get("first_index", 0))
    lo = int(run.meta.get("ramp_end_index", first)) - first
    hi = int(run.meta.get("settled_end_index", first + pr.size)) - first
    m = int(round(length / dt))
    if m < 20:
        raise ValueError(f"decay window length {length} s is too short (need >= 20 samples "
                         f"= {20 * dt:g} s)")  # fmt: skip
    mx = m if max_length is None else int(round(max_length / dt))
    if mx < m:
        raise ValueError(f"longest decay window {max_length} s is shorter than the shortest "
                         f"({length} s); give max_length >= length")  # fmt: skip
    part = pr[lo:hi] if hi - lo >= 20 else pr
    sigma = 1.4826 * float(np.median(np.abs(part - np.median(part))))
    thr = max(DECAY_K * sigma, DECAY_MIN_PEAK)
    pre, gap = int(round(1.0 / dt)), int(round(0.15 / dt))
    speed = float(run.meta.get("speed", np.nan))
    out: list[Segment] = []
    i, pushed = max(lo, pre), False
    while i < hi - m:
        if abs(pr[i]) <= thr:
            i += 1
            continue
        sgn, k = np.sign(pr[i]), i
        while k + 1 < hi and sgn * pr[k + 1] > 0.5 * thr:  # the push's first lobe
            k += 1
        j = i + int(np.argmax(sgn * pr[i : k + 1]))
        peak = abs(pr[j])
        before = float(np.max(np.abs(pr[i - pre : i - gap])))
        if peak <= DECAY_REGROW * before and not pushed:  # a lobe of the motion before
            i = k + 1
            continue
        s = j + _settle(pr, j, max(i - pre, 0), peak, dt)  # the window starts here
        n, nxt = 0, s + m
        if s + m > hi:
            why = "runs past the end of the settled speed"
        elif before >= DECAY_QUIET * peak:
            why = f"not at rest in the second before the push (>= {DECAY_QUIET} x peak)"
        else:
            ref = _response_peak(sgn * pr[s : s + m], peak, thr)
            n, why, nxt = _decay_length(pr[s : min(s + mx, hi)], m, ref, thr, dt)
            if why.startswith("does not decay") and hi - s < mx:
                why = (f"runs past the end of the settled speed before it decays (second half "
                       f">= {DECAY_RATIO} x peak)")  # fmt: skip
            nxt += s
        if n:
            out.append(Segment(run.meta.get("file", "?"), speed, first + s, first + s + n))
        elif rejected is not None:
            rejected.append((first + j, why))  # the push's peak: where a user finds it
        i, pushed = nxt, why.startswith("a second push")  # the next lobe is that push
    return out


def _settle(pr: np.ndarray, j: int, lo: int, peak: float, dt: float) -> int:
    """Samples from the roll-rate extreme ``j`` to the window's start: :data:`DECAY_SETTLE`
    x the push's rise (from its onset, the last sample after ``lo`` with |roll rate| below
    :data:`DECAY_ONSET` x ``peak``, to the extreme), at most :data:`DECAY_MAX_SETTLE`."""
    quiet = np.flatnonzero(np.abs(pr[lo:j]) < DECAY_ONSET * peak)
    rise = j - (lo + int(quiet[-1]) if quiet.size else lo)
    return min(int(round(DECAY_SETTLE * rise)), int(round(DECAY_MAX_SETTLE / dt)))


def _response_peak(x: np.ndarray, peak: float, thr: float) -> float:
    """The peak a window's decay is measured against: the larger of the push's ``peak`` and
    its response (the first lobe of the other sign in ``x``, the roll rate from the window's
    start times the push's sign [rad/s], beyond ``thr`` / 2), when that lobe is at most
    :data:`DECAY_RESPONSE_MAX` x ``peak``; else ``peak`` (a larger lobe is a second push,
    rejected as rising)."""
    back = np.flatnonzero(x < -0.5 * thr)
    if not back.size:
        return peak
    end = np.flatnonzero(x[back[0] :] >= 0)
    r = float(-np.min(x[back[0] : back[0] + (end[0] if end.size else x.size)]))
    return r if peak < r <= DECAY_RESPONSE_MAX * peak else peak


def _decay_length(
    x: np.ndarray, m: int, peak: float, thr: float, dt: float
) -> tuple[int, str, int]:
    """One push's window: ``x`` is the roll rate from its peak on [rad/s], at most the longest
    window long (or to the end of the settled speed); ``m`` the shortest window [samples];
    ``thr`` the onset threshold [rad/s].

    Returns (the kept length [samples], 0 when rejected; the reason, "" when kept; the
    sample, counted from the peak, where the search for the next push goes on).
    """
    a = np.abs(x)
    top = np.maximum.accumulate(a)
    if top[m - 1] > 1.1 * peak:
        return 0, _RISES, m
    if np.max(a[m // 2 : m]) < DECAY_RATIO * peak:
        return m, "", m  # the fixed window: no further test
    if a.size == m:
        return 0, f"does not decay (second half >= {DECAY_RATIO} x peak)", m
    q = _second_push(x, thr, int(round(DECAY_LULL / dt)))  # a longer window ends before it
    for n in range(m + 1, min(q, a.size) + 1):
        if top[n - 1] > 1.1 * peak:
            return 0, _RISES, n
        if np.max(a[n // 2 : n]) < DECAY_RATIO * peak:
            return n, "", n
    if q < a.size:
        return 0, f"a second push {q * dt:.2f} s into the window, before it decayed", q
    return 0, (f"does not decay within {a.size * dt:.3g} s (second half >= {DECAY_RATIO} x "
               "peak)"), a.size  # fmt: skip


def _second_push(x: np.ndarray, thr: float, lull: int) -> int:
    """The first sample of a second push in ``x`` (roll rate from a push's peak on), or
    ``x.size``.  Lobes are the excursions beyond -+ ``thr`` / 2 (a sign change there starts
    the next; noise near zero starts none); a free decay's lobes each rise and fall once
    and shrink.  A lobe's |roll rate| rising above the onset threshold ``thr`` marks a
    second push (at the lobe's start, or where it rose again) when: the lobe starts after
    ``lull`` samples within thr / 2 (the decay's own oscillation crosses that band in at
    most 1.05 / omega s); it rises again within the lobe, above :data:`DECAY_REGROW` x the
    lobe's extreme so far after falling below half of it (a lobe that had risen above
    ``thr``: noise at the band's edge makes no dip); or, after the push's own lobe
    and the next (its response, which may be the larger), it rises above DECAY_REGROW x
    every lobe since the push's own."""
    h = 0.5 * thr
    sgn = 1.0 if x[0] >= 0 else -1.0
    k, ext, before, start, calm, fresh, dip = 0, 0.0, 0.0, 0, 0, False, -1
    for t, v in enumerate(x):
        u = abs(v)
        if u < h:
            calm += 1
        else:
            if sgn * v < 0 or calm >= lull:  # the next lobe
                if k >= 1:
                    before = max(before, ext)
                sgn, k, ext, start, fresh, dip = np.sign(v), k + 1, 0.0, t, calm >= lull, -1
            calm = 0
        if dip < 0 and ext > thr and u < 0.5 * ext:
            dip = t  # the lobe has fallen: a rise above its extreme is another push
        if u > thr and u > DECAY_REGROW * ext and dip >= 0:
            return dip
        ext = max(ext, u)
        if ext > thr and k >= 1 and (fresh or (k >= 2 and ext > DECAY_REGROW * before)):
            return start
    return x.size


_RISES = "rises above 1.1 x its peak inside the window (a second push, or the push still acting)"


def iter_decays(
    root: str | os.PathLike, source: str = "listed"
) -> Iterator[tuple[Run, list[Segment]]]:
    """(run, its free-decay windows) for every eigen log (name starting ``eigen``) under root.

    ``source="listed"``: the windows of ``segments.csv`` (in the log's folder) for the logs
    it lists, :func:`detect_decays` for the others, so a new log of this format needs no
    segments file.  ``source="detected"``: :func:`detect_decays` for every log.

    Parameters
    ----------
    root : str or path-like
        Folder searched recursively.
    source : str, optional
        ``"listed"`` or ``"detected"``.

    Yields
    ------
    (Run, list of Segment)
        Each eigen log (:func:`bikeid.dataset.sbw_logs.load_log`) with its non-empty
        list of windows; logs without a window are skipped.

    Raises
    ------
    ValueError
        For an unknown ``source``, or a malformed ``segments.csv``
        (:func:`read_segments`).
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


#: Fewest usable decays ``measured fit`` accepts: the selection fits on every second decay
#: and checks each effect on the others, so it needs at least two in each half.
MIN_FIT_DECAYS = 4


def _file_of(run: Run) -> str:
    """The log's file name: ``meta["file"]``, else the importer's, else ``"run"``."""
    return str(run.meta.get("file") or run.meta.get("import", {}).get("file") or "run")


def decays_from_runs(
    runs: list[Run],
    source: str = "detected",
    listed: dict[str, list[Segment]] | None = None,
    speeds: list[float] | None = None,
    exclude: list[float] | None = None,
    min_decays: int = 1,
    purpose: str = "the fit",
) -> tuple[list[Window], dict]:
    """Free-decay windows of any logs (steer-by-wire or imported), with what was rejected.

    Each run's decays are its ``listed`` segments (``source="listed"`` and the run's file has
    some) or else detected from its roll rate (:func:`detect_decays`; no segments file
    needed).  Windows are :func:`bikeid.dataset.windows.decay_windows` of the run, each with
    the run's speed (``meta["speed"]``, [m/s]).

    Parameters
    ----------
    runs : list of Run
        The logs (:func:`bikeid.dataset.sbw_logs.load_log`, or
        :func:`bikeid.dataset.importers.from_csv` / ``from_hdf5``).
    source : str, optional
        ``"detected"`` (default) or ``"listed"``.
    listed : dict of str to list of Segment, optional
        Listed windows by file name (``segments.csv`` rows).
    speeds, exclude : list of float, optional
        Keep only / drop windows within 0.25 m/s of these speeds [m/s].
    min_decays : int, optional
        Fewest windows accepted (default 1); fewer is refused.
    purpose : str, optional
        What the windows are for, in the refusal (e.g. ``"the fit"``).

    Returns
    -------
    windows : list of Window
        In the order of ``runs``, each run's in time order; ``meta["dt"]`` the log's sample
        period [s].
    report : dict
        ``decays`` (count kept), ``files``: per log its ``file``, ``speed`` [m/s],
        ``source`` (``listed`` or ``detected``), ``kept`` and ``rejected`` (the detected
        pushes not kept: ``[row, reason]``).

    Raises
    ------
    bikeid.sim.errors.InputError
        For an unknown ``source``; when fewer than ``min_decays`` windows are left (the
        message gives how many were found per log and why the others were rejected); or
        when the speed selection leaves none (naming the speeds the data has).
    """
    if source not in ("listed", "detected"):
        raise InputError(f"unknown decay source {source!r}; use 'listed' or 'detected'")
    out: list[Window] = []
    files = []
    for run in runs:
        name = _file_of(run)
        if run.meta.get("file") != name:
            run = replace(run, meta={**run.meta, "file": name})
        segs = list((listed or {}).get(name, [])) if source == "listed" else []
        rejected: list = []
        how = "listed" if segs else "detected"
        if not segs:
            segs = detect_decays(run, rejected=rejected)
        ws = decay_windows(run, segs) if segs else []
        dt = float(run.meta.get("dt") or run.dt)
        out.extend(replace(w, meta={**w.meta, "dt": dt}) for w in ws)  # the log's period [s]
        files.append({"file": name, "speed": float(run.speed), "source": how, "kept": len(ws),
                      "rejected": [[int(r), why] for r, why in rejected]})  # fmt: skip
    have = sorted({round(w.speed, 2) for w in out})
    if out and (speeds is not None or exclude):
        keep = [w for w in out if (speeds is None or _near(w, speeds))
                and not (exclude and _near(w, exclude))]  # fmt: skip
        if not keep:
            raise InputError(f"no decay windows at the requested speeds; the data has {have} m/s")
        out = keep
    if len(out) < min_decays:
        raise InputError(_too_few(files, len(out), min_decays, purpose))
    return out, {"decays": len(out), "files": files}


def _near(w: Window, lst: list[float]) -> bool:
    return any(abs(w.speed - s) < 0.25 for s in lst)


def _too_few(files: list[dict], n: int, need: int, purpose: str) -> str:
    """The refusal of :func:`decays_from_runs`: counts per log and the rejection reasons."""
    parts = []
    for f in files:
        why: dict[str, int] = {}
        for _, r in f["rejected"]:
            why[r] = why.get(r, 0) + 1
        pushes = f["kept"] + len(f["rejected"])
        if pushes == 0:
            parts.append(f"{f['file']}: no push found (|roll rate| never rose above "
                         f"max({DECAY_K:g} robust sigma, {DECAY_MIN_PEAK} rad/s))")  # fmt: skip
            continue
        rej = "; ".join(f"{c} {r}" for r, c in why.items())
        parts.append(f"{f['file']}: {pushes} pushes, {f['kept']} kept"
                     + (f", rejected: {rej}" if rej else ""))  # fmt: skip
    return (f"{n} usable free decay(s) in {len(files)} log(s); {purpose} needs at least "
            f"{need}. " + " | ".join(parts) + ". Log more pushes, each from rest and followed "
            f"by free motion that halves within {DECAY_MAX_LENGTH:g} s (at least "
            f"{DECAY_LENGTH:g} s of it)")  # fmt: skip


def steer_by_wire_logs(
    paths: list[Path], source: str = "listed"
) -> tuple[list[Run], dict[str, list[Segment]]]:
    """Steer-by-wire eigen logs read, with the ``segments.csv`` rows beside them.

    Parameters
    ----------
    paths : list of Path
        ``*.log[.gz]`` files (:func:`bikeid.dataset.sbw_logs.find_logs`).
    source : str, optional
        ``"listed"``: read the ``segments.csv`` in each log's folder; ``"detected"``: none.

    Returns
    -------
    runs : list of Run
        :func:`bikeid.dataset.sbw_logs.load_log` of each path.
    listed : dict of str to list of Segment
        The listed windows by file name (empty for ``"detected"``).

    Raises
    ------
    ValueError
        A log or a ``segments.csv`` that cannot be read (naming it).
    """
    runs, listed = [], {}
    lists: dict[Path, list[Segment]] = {}
    for path in map(Path, paths):
        sf = path.parent / "segments.csv"
        if source == "listed" and sf.is_file() and sf not in lists:
            lists[sf] = read_segments(sf)
            for sg in lists[sf]:
                listed.setdefault(sg.file, []).append(sg)
        runs.append(load_log(path))
    return runs, listed


def load_decays(
    data: str | os.PathLike | None,
    speeds: list[float] | None = None,
    exclude: list[float] | None = None,
    source: str = "listed",
) -> list[Window]:
    """Free-decay windows of all eigen logs, optionally only near some speeds.

    The steer-by-wire folder read through :func:`decays_from_runs`, the path of any logs.

    Parameters
    ----------
    data : str or path-like or None
        The data folder (:func:`bikeid.dataset.sbw_logs.data_dir`; None: ``$BIKEID_DATA``).
    speeds : list of float, optional
        Keep only windows within 0.25 m/s of one of these treadmill speeds [m/s].
    exclude : list of float, optional
        Drop windows within 0.25 m/s of one of these treadmill speeds [m/s].
    source : str, optional
        ``"listed"`` or ``"detected"`` (:func:`iter_decays`).

    Returns
    -------
    list of Window
        The free-decay windows (:func:`bikeid.dataset.windows.decay_windows`).

    Raises
    ------
    ValueError
        When the data has no free-decay window at all, or none is left after the speed
        selection (the message names the speeds the data has).
    """
    root = data_dir(data)
    if source not in ("listed", "detected"):
        raise ValueError(f"unknown decay source {source!r}; use 'listed' or 'detected'")
    runs, listed = steer_by_wire_logs(find_logs(root, "eigen"), source)
    if not runs:
        raise ValueError(
            f"{root}: no free-decay windows (need eigen*.log[.gz] logs with pushes the detector "
            "finds, or rows for them in eigen/segments.csv)"
        )
    try:
        out, _ = decays_from_runs(runs, source, listed, speeds, exclude, min_decays=1)
    except InputError as exc:
        if "usable free decay" not in str(exc):
            raise
        raise ValueError(
            f"{root}: no free-decay windows (need eigen*.log[.gz] logs with pushes the detector "
            "finds, or rows for them in eigen/segments.csv)"
        ) from None
    return out
