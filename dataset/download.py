"""Download of the pinned steer-by-wire logs (``bikeid data fetch``).

Files come from the upstream repository at a pinned commit, are gzip-compressed and written
atomically through :func:`bikeid.dataset.files.atomic_write_bytes`; the SHA-256 of the
upstream bytes is recorded in ``checksums.json`` and checked on every later download.
"""

from __future__ import annotations

import contextlib
import gzip
import hashlib
import json
import os
import urllib.request
from collections.abc import Callable
from pathlib import Path

from bikeid.dataset.files import atomic_write_bytes, atomic_write_text
from bikeid.dataset.sbw_logs import DATASET

__all__ = ["CAMPAIGN", "PINNED", "UPSTREAM_COMMIT", "fetch"]

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
    commit), gzip-compressed and written atomically (:mod:`bikeid.dataset.files`).  The SHA-256
    of the upstream bytes is recorded in ``checksums.json`` on first download and
    checked on every later one.  Every file is downloaded and checked before anything is
    written: a failed download or a checksum mismatch (ValueError) writes nothing, and a
    failure while writing (a full disk) removes the files and folders the call made.
    ``segments.csv`` is not an upstream file (it was transcribed from the source's
    analysis script) and is not fetched: in a fetched folder the decay windows are
    detected (:func:`bikeid.dataset.decays.detect_decays`).  Returns {local path: sha256}.

    Parameters
    ----------
    dest : str or path-like
        Folder to create ``tudelft-sbw/`` in.
    commit : str, optional
        Upstream commit (default :data:`UPSTREAM_COMMIT`).
    opener : callable, optional
        url -> bytes (default: HTTP download with a 60 s timeout).
    url_pattern : str, optional
        With ``{repo}``, ``{commit}``, ``{path}``.
    files : dict of str to str, optional
        Local path -> upstream path (default :data:`PINNED`).

    Returns
    -------
    dict of str to str
        Local path -> SHA-256 of the upstream bytes.

    Raises
    ------
    ValueError
        On a checksum mismatch with ``checksums.json`` (the message names the file and
        when to delete the record), or when a download fails (the message gives the URL
        and the ``--data`` / ``BIKEID_DATA`` alternative).
    """
    opener = opener or _urlopen
    files = PINNED if files is None else files
    root = Path(dest) / DATASET
    sums_path = root / "checksums.json"
    sums = json.loads(sums_path.read_text()) if sums_path.is_file() else {}
    fetched = {}  # everything is downloaded and checked before anything is written
    for local, remote in files.items():
        url = url_pattern.format(repo=UPSTREAM_REPO, commit=commit, path=remote)
        data = opener(url)
        digest = _sha256(data)
        if local in sums and sums[local] != digest:
            raise ValueError(
                f"checksum mismatch for {local}: recorded {sums[local][:12]}..., got "
                f"{digest[:12]}...; delete {sums_path} only if the upstream file really changed"
            )
        fetched[local] = (data, digest)
    made: list[Path] = []  # folders and files this call creates, removed again on a failure
    try:
        for folder in (root, *sorted({(root / local).parent for local in fetched})):
            missing = [q for q in (folder, *folder.parents) if not q.exists()]
            for q in reversed(missing):
                q.mkdir()
                made.append(q)
        out = {}
        for local, (data, digest) in fetched.items():
            target = root / local
            if not target.exists():
                made.append(target)
            payload = gzip.compress(data, mtime=0) if local.endswith(".gz") else data
            atomic_write_bytes(target, payload)
            sums[local] = digest
            out[local] = digest
        if not sums_path.exists():
            made.append(sums_path)
        atomic_write_text(sums_path, json.dumps(sums, indent=2, sort_keys=True) + "\n")
    except BaseException:
        for q in reversed(made):  # a failed fetch leaves nothing it made behind
            with contextlib.suppress(OSError):
                q.rmdir() if q.is_dir() else q.unlink()
        raise
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
