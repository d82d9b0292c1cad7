"""Writing a user's files safely: the one implementation every output of bikeid goes through.

A file is written to a temporary file created by :func:`tempfile.mkstemp` in the target's
own folder (exclusive creation with an unpredictable name, so a planted symlink is never
followed), flushed and fsynced, given its final mode, then renamed over the target with
:func:`os.replace` (atomic on POSIX) and the folder fsynced.  On any error, or an interrupt,
the temporary file is removed and the target is left exactly as it was.

Targets that are not regular files (a character device such as ``/dev/null``, a folder, a
FIFO, a socket) are refused, never replaced; a symlink at the target is refused too, because
replacing it would silently turn the user's link into a file.  A new file gets the mode
``0o666 & ~umask`` (what ``open(path, "w")`` would give); an existing file keeps its mode.
The temporary file's name carries the writer's process id (``.NAME.PID.XXXXXXXX.tmp``), so
the next write of the same target removes those left by a killed process.  A full disk, an
I/O error or a read-only medium is one :class:`~bikeid.sim.errors.InputError` naming the
file and the free space (:func:`storage_error`), never a partial target.

The same module holds the checks every command makes before any work:

- :func:`check_outputs`: no output is (or, for a folder, contains) one of the command's
  inputs, compared by device and inode so that links and other spellings are caught;
  inputs are regular files or folders (a device or FIFO is refused);
- :func:`check_distinct_inputs`: the same data given twice (same file, or same content by
  SHA-256) is refused instead of silently counted twice;
- :func:`check_free_space`: a write's estimated size against the free space of its folder;
- :func:`read_bounded`: a file's bytes (``.gz`` decompressed in a stream) with its size
  estimated against the memory limit before reading, and a cap on the compression ratio;
- :func:`owned_folder`: an output folder a command owns: a marker listing the files it
  wrote is written first, files it did not write are refused by name, a lock keeps two runs
  from mixing one folder, and an interrupted run can be rerun into the same folder.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import stat
import tempfile
import threading
import zlib
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path

from bikeid.sim.errors import InputError, check_memory, memory_limit

__all__ = [
    "MAX_EXPANSION",
    "MARKER",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_text",
    "check_distinct_inputs",
    "check_free_space",
    "check_h5_dataset",
    "check_input_file",
    "check_output_path",
    "check_outputs",
    "check_owned_folder",
    "owned_folder",
    "read_bounded",
    "sha256_file",
    "size_text",
    "storage_error",
]

#: Largest decompressed/stored size ratio accepted from a compressed input (a ``.gz`` log, a
#: compressed HDF5 dataset).  Real logs compress 3-5 times; a "bomb" thousands of times.
MAX_EXPANSION = 100
#: Name of the marker file of a folder a command owns (:func:`owned_folder`).
MARKER = ".bikeid-folder.json"
_LOCK = ".bikeid-folder.lock"
#: errno values that mean "the medium cannot take this write" (not a bug, not bad data).
_STORAGE_ERRNOS = {errno.ENOSPC, errno.EDQUOT, errno.EIO, errno.EROFS, errno.EFBIG}


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_output_path(path: str | os.PathLike) -> Path:
    """Refuse an output target that is not (or would not be) a regular file.

    Parameters
    ----------
    path : str or path-like
        The file a command is about to write.

    Returns
    -------
    pathlib.Path
        ``path`` as a :class:`~pathlib.Path`.

    Raises
    ------
    ValueError
        If ``path`` is a symlink, a folder, a device, a FIFO or a socket, cannot be
        inspected (``os.lstat`` fails other than with "not found"), or its folder
        exists as something other than a folder.
    """
    path = Path(path)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise ValueError(f"cannot write {path}: {exc.strerror}") from None
    if st is not None:
        if stat.S_ISLNK(st.st_mode):
            raise ValueError(
                f"{path} is a symbolic link; bikeid does not write through links (it would "
                "replace the link by a file): give the link's target or another name"
            )
        if not stat.S_ISREG(st.st_mode):
            kind = "a folder" if stat.S_ISDIR(st.st_mode) else "not a regular file"
            raise ValueError(f"{path} is {kind}; give the name of a regular file to write")
    parent = path.parent
    if parent.exists() and not parent.is_dir():
        raise ValueError(f"cannot write {path}: {parent} is not a folder")
    return path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` atomically.

    Parameters
    ----------
    path : str or path-like
        The final file.  Its folder is created if missing.

    Yields
    ------
    pathlib.Path
        A freshly created, empty temporary file ``.NAME.XXXXXXXX.tmp`` in the same folder.
        Write it inside the ``with`` block (writers that infer a format from the suffix,
        like matplotlib's ``savefig``, need the format named explicitly).

    Raises
    ------
    ValueError
        If ``path`` is not a regular file (:func:`check_output_path`).
    """
    path = check_output_path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        mode = stat.S_IMODE(os.stat(path).st_mode)
    except FileNotFoundError:
        mode = 0o666 & ~_umask()
    _remove_stale_temporaries(path)
    _claim(path)
    try:
        fd, tmp = tempfile.mkstemp(
            dir=path.parent, prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp"
        )
    except OSError as exc:
        raise storage_error(exc, path) from None
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        check_output_path(path)  # refuse a link or device planted while we wrote
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise storage_error(exc, path) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    with contextlib.suppress(OSError):  # make the rename durable (not possible everywhere)
        dfd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Write bytes to a file atomically (:func:`atomic_path`).

    Parameters
    ----------
    path : str or path-like
        The final file; its folder is created if missing.
    data : bytes
        The complete new content.

    Raises
    ------
    ValueError
        If ``path`` is not (or would not be) a regular file (:func:`check_output_path`).
    """
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(data)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write text (UTF-8) to a file atomically (:func:`atomic_path`).

    Parameters
    ----------
    path : str or path-like
        The final file; its folder is created if missing.
    text : str
        The complete new content, encoded as UTF-8.

    Raises
    ------
    ValueError
        If ``path`` is not (or would not be) a regular file (:func:`check_output_path`).
    """
    atomic_write_bytes(path, text.encode("utf-8"))


# -- sizes and storage faults -----------------------------------------------------------
def size_text(nbytes: float) -> str:
    """A byte count for a message: ``"3.2 MiB"``.

    Parameters
    ----------
    nbytes : float
        Size [bytes].

    Returns
    -------
    str
        Three significant digits and a binary unit.
    """
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB"):
        if abs(nbytes) < 1024 or unit == "TiB":
            return f"{nbytes:.3g} {unit}"
        nbytes /= 1024
    return f"{nbytes:.3g} TiB"  # pragma: no cover


def _free_bytes(folder: Path) -> int | None:
    """Free bytes for an unprivileged writer in ``folder`` (or its nearest existing parent)."""
    folder = Path(folder)
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        st = os.statvfs(folder)
    except (OSError, AttributeError):  # not POSIX, or the folder vanished
        return None
    return int(st.f_bavail) * int(st.f_frsize)


def storage_error(exc: OSError, path: str | os.PathLike, need: float | None = None):
    """The one-line error of a write the medium refused (full, read-only, I/O error).

    Parameters
    ----------
    exc : OSError
        The error of the write.
    path : str or path-like
        The file being written (named in the message).
    need : float, optional
        Estimated size of the write [bytes], named in the message when known.

    Returns
    -------
    BaseException
        An :class:`~bikeid.sim.errors.InputError` (exit status 3) naming the file, the
        cause, the free space and the fix for ENOSPC, EDQUOT, EIO, EROFS and EFBIG; ``exc``
        itself for any other error (to be raised as it was).
    """
    if exc.errno not in _STORAGE_ERRNOS:
        return exc
    path = Path(path)
    free = _free_bytes(path.parent)
    have = "" if free is None else f"; {size_text(free)} free there"
    want = "" if need is None else f", about {size_text(need)} needed"
    fix = {
        errno.EROFS: "write to a writable folder",
        errno.EIO: "check the medium (an I/O error) or write elsewhere",
    }.get(exc.errno, "free some space or write to another disk")
    return InputError(
        f"cannot write {path}: {exc.strerror or os.strerror(exc.errno)}{want}{have}; {fix}, "
        "then rerun (the target is left as it was, finished parts of a sweep are kept)"
    )


def check_free_space(path: str | os.PathLike, need: float, margin: float = 1.1) -> None:
    """Refuse a write of about ``need`` bytes that its folder's free space cannot hold.

    Used before HDF5 writes, whose library cannot always fail cleanly on a full disk.

    Parameters
    ----------
    path : str or path-like
        The file to write.
    need : float
        Estimated size of the write [bytes].
    margin : float, optional
        Factor on ``need`` for metadata and the temporary copy (default 1.1).

    Raises
    ------
    InputError
        If the folder (or its nearest existing parent) has less than ``margin * need``
        bytes free, naming the file, both sizes and the fix.
    """
    free = _free_bytes(Path(path).parent)
    want = float(need) * margin
    if free is not None and want > free:
        raise InputError(
            f"cannot write {path}: it needs about {size_text(want)} but only "
            f"{size_text(free)} is free there; free some space or write to another disk"
        )


def check_h5_dataset(ds, where: str, fix: str = "write it again with bikeid") -> None:
    """Refuse, before reading, an HDF5 object bikeid cannot trust to be its data.

    Parameters
    ----------
    ds : h5py object
        What a path in the file resolved to (links followed).
    where : str
        The file and the path, named in messages.
    fix : str, optional
        What the user can do (default: rewrite the file with bikeid).

    Raises
    ------
    ValueError
        If it is not a dataset (a group where a dataset is expected), a virtual dataset
        (its data in other files, missing ones read as fill values) or one with external
        storage, or declares more samples than the file stores (over
        :data:`~bikeid.dataset.files.MAX_EXPANSION` times, e.g. unwritten chunks);
        :class:`~bikeid.sim.errors.InputError` if it would not fit in memory.
    """
    import h5py  # optional format: loaded only when an HDF5 file is read
    import numpy as np

    if not isinstance(ds, h5py.Dataset):
        raise ValueError(f"{where} is a {type(ds).__name__.lower()} where a dataset is expected; "
                         f"the file is malformed: {fix}")  # fmt: skip
    if ds.is_virtual:
        raise ValueError(
            f"{where} is a virtual dataset (its data live in other files, read as fill values "
            f"where they are missing); give a file that holds its own data: {fix}"
        )
    if ds.external:
        raise ValueError(
            f"{where} keeps its data in external files {[e[0] for e in ds.external][:3]}; give "
            f"a file that holds its own data: {fix}"
        )
    size = int(np.prod(ds.shape, dtype=float)) if ds.shape else 1
    check_memory(size, 1, where, "the file declares more samples than memory holds; split "
                 "the data")  # fmt: skip
    nbytes = size * ds.dtype.itemsize
    stored = ds.id.get_storage_size()
    if nbytes > 1 << 16 and stored * MAX_EXPANSION < nbytes:
        raise ValueError(
            f"{where} declares {size:,} samples ({size_text(nbytes)}) but stores "
            f"{size_text(stored)} (more than {MAX_EXPANSION} times less); the file is damaged "
            f"or its data were never written: {fix}"
        )


# -- inputs -------------------------------------------------------------------------------
def _stat(path: Path) -> os.stat_result | None:
    try:
        return os.stat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:
        raise InputError(f"cannot read {path}: {exc.strerror}; check the name") from None
    except ValueError:  # an embedded NUL byte
        raise InputError(f"{str(path)!r} is not a valid file name") from None


def check_input_file(path: str | os.PathLike, what: str = "input") -> int:
    """Refuse an input that is not a regular file (a device, FIFO or socket), before reading.

    Parameters
    ----------
    path : str or path-like
        The input (links are followed).
    what : str, optional
        How it is named in the message (e.g. ``"--model"``).

    Returns
    -------
    int
        Its size [bytes].

    Raises
    ------
    FileNotFoundError
        If it does not exist.
    InputError
        If it is a folder, a device, a FIFO or a socket (reading it could block or never
        end), naming it and the fix.
    """
    path = Path(path)
    st = _stat(path)
    if st is None:
        raise FileNotFoundError(errno.ENOENT, f"{what} {path}: no such file", str(path))
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{what} {path} is a folder; give a file")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(
            f"{what} {path} is not a regular file (a device, FIFO or socket); give a file"
        )
    return int(st.st_size)


def check_outputs(
    outputs: Iterable[str | os.PathLike | None], inputs: Iterable[str | os.PathLike | None]
) -> None:
    """Refuse, before any work, an output that is one of the inputs or a folder holding one.

    Files are compared by device and inode (so a symlink, a hard link or another spelling
    of an input is caught); an output folder is refused when an input file lies anywhere
    under it.  Inputs must be regular files or folders.

    Parameters
    ----------
    outputs : iterable of path or None
        The files and folders the command will write (None entries are skipped).
    inputs : iterable of path or None
        The files and folders it reads (None and missing entries are skipped: their
        readers report them).

    Raises
    ------
    InputError
        If an input is a device, FIFO or socket, or an output is (or contains) an input,
        naming both and the fix.
    """
    ins: list[tuple[Path, os.stat_result]] = []
    for p in inputs:
        if p is None or str(p) == "":
            continue
        p = Path(p)
        st = _stat(p)
        if st is None:
            continue
        if not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)):
            raise InputError(
                f"input {p} is not a regular file (a device, FIFO or socket); give a file"
            )
        ins.append((p, st))
    for out in outputs:
        if out is None or str(out) == "":
            continue
        out = Path(out)
        st = _stat(out)
        for p, sp in ins:
            same = st is not None and (st.st_dev, st.st_ino) == (sp.st_dev, sp.st_ino)
            if same:
                raise InputError(
                    f"output {out} is the input {p} (the same file on disk); bikeid never "
                    "overwrites its inputs: give the output another name"
                )
            if st is not None and stat.S_ISDIR(st.st_mode) and not stat.S_ISDIR(sp.st_mode):
                try:
                    inside = Path(os.path.realpath(p)).is_relative_to(os.path.realpath(out))
                except (OSError, ValueError):
                    inside = False
                if inside:
                    raise InputError(
                        f"output folder {out} holds the input {p}; bikeid never writes where "
                        "its inputs are: give another output folder"
                    )


def sha256_file(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes, read in 1 MiB blocks.

    Parameters
    ----------
    path : str or path-like
        The file.

    Returns
    -------
    str
        Hex digest (64 characters).

    Raises
    ------
    OSError
        If the file cannot be read.
    """
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def check_distinct_inputs(paths: Sequence[str | os.PathLike]) -> None:
    """Refuse the same data given twice: one file under two names, or two equal files.

    Counting a run twice shrinks every interval by sqrt(2) with no sign of it.

    Parameters
    ----------
    paths : sequence of path
        The data files of one command (missing ones are skipped: their readers report them).

    Raises
    ------
    InputError
        If two entries are the same file (device and inode) or have the same content
        (SHA-256), naming both and the fix.
    """
    seen: dict[tuple[int, int], Path] = {}
    by_size: dict[int, list[Path]] = {}
    for p in map(Path, paths):
        st = _stat(p)
        if st is None or not stat.S_ISREG(st.st_mode):
            continue
        key = (st.st_dev, st.st_ino)
        if key in seen:
            raise InputError(
                f"{p} and {seen[key]} are the same file; give each data file once (it would "
                "count twice and every interval would be too narrow)"
            )
        seen[key] = p
        by_size.setdefault(int(st.st_size), []).append(p)
    for group in by_size.values():
        if len(group) < 2:
            continue
        digests: dict[str, Path] = {}
        for p in group:
            d = sha256_file(p)
            if d in digests:
                raise InputError(
                    f"{p} and {digests[d]} hold the same data (equal SHA-256); give each data "
                    "file once (it would count twice and every interval would be too narrow)"
                )
            digests[d] = p


def read_bounded(path: str | os.PathLike, label: str, expansion: float = 1.0) -> bytes:
    """A file's bytes (a ``.gz`` file decompressed), refused before it can exhaust memory.

    The memory a reader needs is estimated as ``expansion`` times the (decompressed) size
    and compared with :func:`bikeid.sim.errors.memory_limit`; a ``.gz`` file is decompressed
    in a stream and refused as soon as it exceeds that bound or :data:`MAX_EXPANSION` times
    its compressed size.

    Parameters
    ----------
    path : str or path-like
        A regular file (:func:`check_input_file`).
    label : str
        How the file is named in messages.
    expansion : float, optional
        Bytes of memory the caller needs per byte of content (a CSV parsed into floats
        needs about 12), default 1.

    Returns
    -------
    bytes
        The (decompressed) content.

    Raises
    ------
    InputError
        If the file is not regular, is too large for memory, or a ``.gz`` file expands
        more than :data:`MAX_EXPANSION` times; the message names the sizes and the limit.
    ValueError
        If a ``.gz`` file is corrupt or truncated.
    OSError
        If the file cannot be read.
    """
    path = Path(path)
    size = check_input_file(path, label)
    limit = memory_limit()
    cap = limit / max(expansion, 1.0)
    if size > cap:
        raise InputError(
            f"{label} is {size_text(size)}; reading it would take about "
            f"{size_text(size * expansion)}, more than the {size_text(limit)} allowed (half "
            "the memory): split the file"
        )
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise type(exc)(exc.errno, f"cannot read {label} ({exc.strerror})") from None
    if not path.name.endswith(".gz"):
        return raw
    bound = min(cap, MAX_EXPANSION * max(size, 1024))
    d = zlib.decompressobj(wbits=31)
    chunks, total, pos = [], 0, 0
    try:
        while pos < len(raw) or d.unconsumed_tail:
            data = d.unconsumed_tail or raw[pos : pos + (1 << 16)]
            if not d.unconsumed_tail:
                pos += len(data)
            piece = d.decompress(data, 1 << 20)
            total += len(piece)
            if total > bound:
                raise InputError(
                    f"{label} expands to more than {size_text(bound)} (over "
                    f"{total / max(size, 1):.0f} times its {size_text(size)}; at most "
                    f"{MAX_EXPANSION} times and {size_text(cap)} are read): it is not a log "
                    "bikeid can read; decompress it yourself if it is genuine"
                )
            chunks.append(piece)
            if d.eof:
                rest = d.unused_data + raw[pos:]
                if not rest:
                    break
                d = zlib.decompressobj(wbits=31)  # a multi-member gzip file (gzip -c a b)
                raw, pos = rest, 0
        if not d.eof:
            raise EOFError("compressed file ended before the end-of-stream marker")
    except (EOFError, zlib.error) as exc:
        raise ValueError(
            f"{label}: corrupt or truncated gzip file ({exc}); fetch or copy it again"
        ) from None
    return b"".join(chunks)


# -- stale temporary files ------------------------------------------------------------------
def _pid_alive(pid: int) -> bool:
    if pid <= 0:
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def _remove_stale_temporaries(path: Path) -> None:
    """Remove ``.NAME.PID.XXXX.tmp`` files beside ``path`` whose writing process is gone."""
    prefix = f".{path.name}."
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return
    for e in entries:
        name = e.name
        if not (name.startswith(prefix) and name.endswith(".tmp")):
            continue
        pid_text = name[len(prefix) :].split(".", 1)[0]
        if pid_text.isdigit() and not _pid_alive(int(pid_text)):
            with contextlib.suppress(OSError):
                if e.is_file(follow_symlinks=False):
                    os.unlink(e.path)


# -- owned folders --------------------------------------------------------------------------
_OWNED: dict[Path, dict] = {}
_OWNED_LOCK = threading.Lock()


def _write_marker(folder: Path, doc: dict) -> None:
    text = json.dumps(doc, indent=1, sort_keys=True) + "\n"
    target = folder / MARKER
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f"{MARKER}.{os.getpid()}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, target)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise storage_error(exc, target) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _claim(path: Path) -> None:
    """Record ``path`` in the marker of the owned folder it lies in (before it is written)."""
    if not _OWNED:
        return
    real = Path(os.path.realpath(path.parent)) / path.name
    with _OWNED_LOCK:
        for folder, doc in _OWNED.items():
            if not real.is_relative_to(folder):
                continue
            rel = real.relative_to(folder).as_posix()
            if rel in doc["files"]:
                return
            if os.path.lexists(real) and doc.get("_strict", True):
                raise InputError(
                    f"{path} exists and was not written by {doc['command']} into {folder}; "
                    "bikeid does not overwrite other files: give another output folder"
                )
            with contextlib.suppress(OSError, ValueError, TypeError):  # another process's claims
                on_disk = json.loads((folder / MARKER).read_text(encoding="utf-8"))["files"]
                doc["files"] += [f for f in on_disk if f not in doc["files"]]
            doc["files"].append(rel)
            _write_marker(folder, {k: v for k, v in doc.items() if not k.startswith("_")})
            return


def _is_ours(name: str) -> bool:
    return (
        name in (MARKER, _LOCK)
        or (name.startswith(f"{MARKER}.") and name.endswith(".tmp"))
        or (name.startswith(".") and name.endswith(".tmp"))
    )


def _foreign(folder: Path, doc: dict | None, names: Iterable[str] | None) -> list[str]:
    """Entries of ``folder`` the command did not write (only among ``names`` if given).

    A top-level entry is the command's when the marker lists it or a file under it (a
    subfolder holding a recorded file); an empty subfolder holds nothing to protect.
    """
    listed = set(doc["files"]) if doc else set()
    tops = {f.split("/", 1)[0] for f in listed}
    if names is not None:
        return sorted(n for n in names if n not in listed and os.path.lexists(folder / n))
    found = []
    for e in os.scandir(folder):
        if _is_ours(e.name) or e.name in tops:
            continue
        if e.is_dir(follow_symlinks=False) and not any(os.scandir(e.path)):
            continue
        found.append(e.name)
    return sorted(found)


@contextlib.contextmanager
def owned_folder(
    path: str | os.PathLike,
    command: str,
    names: Iterable[str] | None = None,
    adopt: Iterable[str] = (),
) -> Iterator[Path]:
    """Make or reopen an output folder owned by ``command``; every write into it is recorded.

    On entry the folder is created if missing, a lock is taken (``.bikeid-folder.lock``,
    released on exit, so a second run into the same folder is refused while the first
    works), and the marker ``.bikeid-folder.json`` naming the command and the files it
    wrote is read, or written first in a new folder.  An existing folder is refused if it
    holds files the marker does not list (only among ``names`` when they are given: the
    files the command will write), or if another command owns it.  Inside the ``with``
    block each :func:`atomic_path` write under the folder is added to the marker before the
    file appears, so an interrupted run leaves a folder the same command can write again;
    a file that appeared there meanwhile, not written by the command, is refused.
    Temporary files of a killed earlier run are removed on entry (the lock proves no writer
    is left).

    Parameters
    ----------
    path : str or path-like
        The output folder.
    command : str
        The owner, e.g. ``"bikeid reproduce"`` (named in messages and the marker).
    names : iterable of str, optional
        The files (relative to the folder) the command will write, when known in advance:
        other files in the folder are then left alone; by default any file the marker does
        not list is foreign.
    adopt : iterable of str, optional
        Files a folder written before markers existed is recognized by (e.g. a
        ``validation.json`` whose ``command`` is the owner): when one of them holds
        ``"command": command``, the folder's files count as the command's.

    Yields
    ------
    pathlib.Path
        The folder.

    Raises
    ------
    InputError
        If the path is a file or a link, another command owns the folder, it holds files
        the command did not write (named, up to five), or another run holds its lock.
    """
    import fcntl  # POSIX only: loaded where a folder is locked

    folder = Path(path)
    if folder.is_symlink() or (folder.exists() and not folder.is_dir()):
        raise InputError(f"{folder} is not a folder; give a new or empty folder for the output")
    names = None if names is None else [Path(n).as_posix() for n in names]
    existed = folder.exists()
    if existed:  # refuse a foreign folder before putting anything into it
        _inspect(Path(os.path.realpath(folder)), folder, command, names, adopt)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise storage_error(exc, folder / MARKER) from None
    real = Path(os.path.realpath(folder))
    try:
        lock_fd = os.open(real / _LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise storage_error(exc, real / _LOCK) from None
    try:
        try:
            fcntl.flock(lock_fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise InputError(
                f"another bikeid run is writing into {folder} (its lock {_LOCK} is held); "
                "wait for it to finish or give another folder"
            ) from None
        doc = _inspect(real, folder, command, names, adopt)  # again, under the lock
        for root, _, files in os.walk(real):  # temporaries of a killed run (we hold the lock)
            for n in files:
                if n.startswith(".") and n.endswith(".tmp"):
                    with contextlib.suppress(OSError):
                        os.unlink(os.path.join(root, n))
        _write_marker(real, doc)
        doc["_strict"] = True
        with _OWNED_LOCK:
            _OWNED[real] = doc
        try:
            yield folder
        finally:
            with _OWNED_LOCK:
                _OWNED.pop(real, None)
    finally:
        os.close(lock_fd)  # releases the lock


def _inspect(
    real: Path, folder: Path, command: str, names: list[str] | None, adopt: Iterable[str]
) -> dict:
    """The marker of an output folder, refusing another owner and foreign files."""
    doc = None
    marker = real / MARKER
    if marker.is_file():
        try:
            doc = json.loads(marker.read_text(encoding="utf-8"))
            if not (isinstance(doc, dict) and isinstance(doc.get("files"), list)):
                doc = None
        except (OSError, ValueError):
            doc = None
        if doc is None:
            raise InputError(
                f"{marker} is damaged; delete the folder {folder} (written by bikeid) or "
                "give another folder"
            )
    if doc is not None and doc.get("command") != command:
        raise InputError(
            f"{folder} holds the output of {doc.get('command')}, not {command}; give "
            "another folder"
        )
    if doc is None:
        for a in adopt:  # a folder written before markers existed
            with contextlib.suppress(OSError, ValueError, AttributeError):
                old = json.loads((real / a).read_text(encoding="utf-8"))
                if old.get("command") == command:
                    doc = {"command": command, "files": _foreign(real, None, None)}
                    break
    foreign = _foreign(real, doc, names)
    if foreign:
        more = f" and {len(foreign) - 5} more" if len(foreign) > 5 else ""
        raise InputError(
            f"{folder} holds files not written by {command} ({', '.join(foreign[:5])}{more}); "
            "bikeid does not overwrite other files: give a new or empty folder"
        )
    return doc if doc is not None else {"command": command, "files": []}


def check_owned_folder(
    path: str | os.PathLike, command: str, names: Iterable[str] | None = None,
    adopt: Iterable[str] = (),
) -> Path:
    """The checks of :func:`owned_folder` without creating or locking anything (before work).

    Parameters
    ----------
    path : str or path-like
        The output folder (may not exist yet).
    command : str
        The owner, e.g. ``"bikeid validate"``.
    names : iterable of str, optional
        The files the command will write, when known (see :func:`owned_folder`).
    adopt : iterable of str, optional
        Files that mark a folder written before markers existed (see :func:`owned_folder`).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    InputError
        If the path is a file or a link, another command owns the folder, or it holds files
        the command did not write (named).
    """
    folder = Path(path)
    if folder.is_symlink() or (folder.exists() and not folder.is_dir()):
        raise InputError(f"{folder} is not a folder; give a new or empty folder for the output")
    if folder.is_dir():
        names = None if names is None else [Path(n).as_posix() for n in names]
        _inspect(Path(os.path.realpath(folder)), folder, command, names, adopt)
    return folder
