"""The BLAS thread limit (``bikeid.sim.blas``), known both ways: without a thread count in the
environment the context leaves OpenBLAS one thread (read back through threadpoolctl, the
independent source); with one set by the user, it leaves the count alone."""

import numpy as np  # noqa: F401 - loads OpenBLAS, so threadpoolctl sees it
import pytest
from threadpoolctl import threadpool_info

from bikeid.sim.blas import BLAS_THREAD_VARIABLES, one_blas_thread, single_threaded_blas


def _blas_threads() -> list[int]:
    return [p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"]


def test_one_thread_unless_the_user_set_a_count(monkeypatch):
    if not _blas_threads():
        pytest.skip("no BLAS library threadpoolctl can see")
    for k in BLAS_THREAD_VARIABLES:
        monkeypatch.delenv(k, raising=False)
    with one_blas_thread():
        assert set(_blas_threads()) == {1}
    assert single_threaded_blas(_blas_threads)() == [1] * len(_blas_threads())
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    before = _blas_threads()
    with one_blas_thread():
        assert _blas_threads() == before  # the user's setting stands
