"""One helper for the studies that run many independent jobs: local processes or Dask.

Every batch study of :mod:`bikeid.experiments` (sweep, stabilization, accuracy, coverage,
the effect and blind trials, the reproductions) hands its jobs to :func:`imap` or
:func:`map_jobs`:

- ``workers=1`` and no ``dask``: the jobs run one after the other in this process;
- ``workers=N`` > 1: a pool of N local processes
  (:class:`concurrent.futures.ProcessPoolExecutor`);
- ``dask=ADDRESS``: a Dask cluster (``dask="local"`` starts a ``LocalCluster`` of
  ``workers`` single-threaded processes for the call; any other value is the address of a
  running scheduler, e.g. ``tcp://host:8786``).  Needs the optional ``dask`` extra
  (``pip install 'bikeid[dask]'``).

**Same seeds, same numbers.**  A job carries all of its randomness (its seed is part of
the job), and nothing is drawn from worker identity or completion order, so a study gives
bit-identical results whichever way it runs (``tests/experiments/test_parallel.py`` runs one study
both ways).  Results come back to the calling process, which alone writes files, so Dask
workers need no shared file system.  Resuming (skipping finished jobs) is the study's
business: :mod:`bikeid.experiments.testbed.sweep` keeps one part file per finished run.

The function run on the workers must be picklable: a module-level function, or a
:func:`functools.partial` of one.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

from bikeid.sim.errors import InputError

__all__ = ["CONNECT_TIMEOUT", "DASK_HELP", "check_workers", "imap", "map_jobs"]

#: Seconds to wait for a Dask scheduler before giving up.
CONNECT_TIMEOUT = 30.0

#: Help text of every command's ``--dask`` option.
DASK_HELP = (
    "run the jobs on a Dask cluster: a scheduler address (tcp://host:8786) or 'local' for a "
    "LocalCluster of --workers processes; needs pip install 'bikeid[dask]' (same numbers as "
    "local processes)"
)


def check_workers(workers: Any) -> int:
    """The number of worker processes as an int; InputError unless a positive integer.

    Parameters
    ----------
    workers : int
        Requested worker processes.

    Returns
    -------
    int
        ``workers``, >= 1.

    Raises
    ------
    InputError
        If ``workers`` is not a positive whole number.
    """
    try:
        ok = int(workers) == workers and workers >= 1
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise InputError(f"--workers must be a positive integer, got {workers!r}")
    return int(workers)


def _name(fn: Callable[..., Any]) -> str:
    inner = getattr(fn, "func", fn)  # functools.partial
    return getattr(inner, "__name__", "job")


def imap(
    fn: Callable[[Any], Any],
    jobs: Iterable[Any],
    workers: int = 1,
    dask: str | None = None,
    ordered: bool = False,
    upload: Sequence[str] = (),
) -> Iterator[tuple[int, Any]]:
    """``fn(job)`` for every job, yielded as ``(index, result)``.

    Parameters
    ----------
    fn : callable
        Function of one job; picklable when ``workers`` > 1 or with ``dask``.
    jobs : iterable
        The jobs (each carries its own seed); read once, up front.
    workers : int, optional
        Local worker processes (default 1: in this process), or the size of the cluster
        ``dask="local"`` starts.
    dask : str or None, optional
        ``"local"`` or a Dask scheduler address; None (default): local processes.
    ordered : bool, optional
        Yield in job order (results that finish early wait) instead of completion order.
    upload : sequence of str, optional
        Python files the Dask workers must import (``Client.upload_file``: a user's module
        named by ``module:function``); local processes import them from ``sys.path``.

    Yields
    ------
    tuple of (int, object)
        The job's index in ``jobs`` and ``fn(job)``.

    Raises
    ------
    InputError
        If ``workers`` is not a positive integer, Dask is asked for but not installed, or
        the scheduler cannot be reached.
    Exception
        Whatever ``fn`` raises for a job (the remaining jobs are cancelled).
    """
    workers = check_workers(workers)
    jobs = list(jobs)
    if dask:
        source = _dask(fn, jobs, workers, str(dask), tuple(upload))
    elif workers == 1 or len(jobs) <= 1:
        source = ((i, fn(job)) for i, job in enumerate(jobs))
    else:
        source = _processes(fn, jobs, workers)
    if not ordered:
        yield from source
        return
    waiting: dict[int, Any] = {}
    nxt = 0
    for i, result in source:
        waiting[i] = result
        while nxt in waiting:
            yield nxt, waiting.pop(nxt)
            nxt += 1


def map_jobs(
    fn: Callable[[Any], Any], jobs: Iterable[Any], workers: int = 1, dask: str | None = None
) -> list[Any]:
    """``[fn(job) for job in jobs]``, in job order, run as :func:`imap` runs it.

    Parameters
    ----------
    fn : callable
        Function of one job; picklable when ``workers`` > 1 or with ``dask``.
    jobs : iterable
        The jobs.
    workers : int, optional
        Local worker processes (default 1), or the size of a ``dask="local"`` cluster.
    dask : str or None, optional
        ``"local"`` or a Dask scheduler address; None (default): local processes.

    Returns
    -------
    list
        ``fn(job)`` for every job, in the order of ``jobs``.

    Raises
    ------
    InputError
        As :func:`imap`.
    Exception
        Whatever ``fn`` raises for a job.
    """
    return [r for _, r in imap(fn, jobs, workers, dask, ordered=True)]


def _processes(fn, jobs: list, workers: int) -> Iterator[tuple[int, Any]]:
    # lazy: multiprocessing costs ~15 ms and `bikeid --help` imports this module (coverage)
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with ProcessPoolExecutor(max_workers=min(workers, len(jobs))) as pool:
        futures = {pool.submit(fn, job): i for i, job in enumerate(jobs)}
        try:
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise


def _dask(fn, jobs: list, workers: int, address: str,
          upload: tuple[str, ...] = ()) -> Iterator[tuple[int, Any]]:  # fmt: skip
    # lazy: distributed is an optional dependency (the dask extra), needed only with --dask
    try:
        from distributed import Client, LocalCluster
        from distributed import wait as dask_wait
    except ImportError:
        raise InputError("--dask needs 'distributed': pip install 'bikeid[dask]'") from None
    cluster = None
    if address == "local":
        cluster = LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None
        )
        client = Client(cluster)
    else:
        try:
            client = Client(address, timeout=CONNECT_TIMEOUT)
        except (OSError, ValueError, TypeError) as exc:
            raise InputError(
                f"cannot reach the Dask scheduler at {address!r}: {str(exc).splitlines()[0]}; "
                "start one (dask scheduler) or use --dask local"
            ) from None
    try:
        for path in upload:  # a user's module: on every worker's path before any job
            client.upload_file(path)
        # unique keys: a long-lived cluster must never hand back another call's result
        tag = f"bikeid-{_name(fn)}-{uuid.uuid4().hex[:12]}"
        futures = [
            client.submit(fn, job, pure=False, key=f"{tag}-{i}") for i, job in enumerate(jobs)
        ]
        index = {f.key: i for i, f in enumerate(futures)}
        # distributed.as_completed(with_results=True) hung now and then on the 2-core VM
        # with every future finished and both workers idle (about 1 sweep in 20);
        # wait(FIRST_COMPLETED) + result() passed 60 runs in a row
        pending = set(futures)
        try:
            while pending:
                done, pending = dask_wait(pending, return_when="FIRST_COMPLETED")
                for fut in done:
                    yield index[fut.key], fut.result()
        except BaseException:
            client.cancel(list(pending))
            raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
