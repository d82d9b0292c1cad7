"""One BLAS thread for bikeid's numerics: the one implementation of the thread limit.

bikeid's fits and simulations are loops over 3x3 to 10x10 matrices, for which threaded
OpenBLAS only spins; :func:`one_blas_thread` (a context) and :func:`single_threaded_blas` (a
decorator) limit BLAS to one thread unless the user set a count in the environment.  Light
to import (threadpoolctl only when used), so the command line's quick commands can use it.
"""

from __future__ import annotations

__all__ = ["BLAS_THREAD_VARIABLES", "one_blas_thread", "single_threaded_blas"]

#: Environment variables by which a user sets the BLAS thread count; when one is set,
#: :func:`one_blas_thread` leaves the count to it.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread():
    """A context with one BLAS thread, unless the user set a thread count.

    bikeid's numerics are loops over 3x3 to 10x10 matrices, for which threaded OpenBLAS only
    spins: a PEM fit was ~10x slower threaded on a shared 2-core machine (bench_ident), and a
    measured fit took 93 s of CPU with the default threads against 65 s with one, in the
    same 65 s of wall time.  A count set in :data:`BLAS_THREAD_VARIABLES` stands.

    Returns
    -------
    contextlib.AbstractContextManager
        ``threadpoolctl.threadpool_limits(1, user_api="blas")``, or a null context.
    """
    import contextlib
    import os

    if any(os.environ.get(k) for k in BLAS_THREAD_VARIABLES):
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits

    return threadpool_limits(1, user_api="blas")


def single_threaded_blas(func):
    """Run ``func`` under :func:`one_blas_thread` (the fits' loops over small matrices).

    Parameters
    ----------
    func : callable
        The function to wrap.

    Returns
    -------
    callable
        ``func`` with one BLAS thread while it runs (unless the user set a count).
    """
    import functools

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        with one_blas_thread():
            return func(*args, **kwargs)

    return wrapper
