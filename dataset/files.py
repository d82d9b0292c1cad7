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
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text", "check_output_path"]


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
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, mode)
        check_output_path(path)  # refuse a link or device planted while we wrote
        os.replace(tmp, path)
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
