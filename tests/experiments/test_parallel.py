"""The one parallel helper (``experiments.parallel``): the same jobs give the same numbers
in this process, in local worker processes and on a Dask cluster.

The independent reference for every comparison is the plain serial loop ``[fn(j) for j in
jobs]`` (``workers=1``, no pool): a pool or a cluster may only change where and in what
order jobs run, never a number, so the comparisons are exact (``==`` on floats and on
whole result dicts), not within a tolerance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.experiments import parallel
from bikeid.experiments.parallel import check_workers, imap, map_jobs
from bikeid.experiments.testbed.coverage import run_coverage
from bikeid.sim.errors import InputError


@pytest.fixture(scope="module")
def dask_address():
    """An in-process Dask cluster (threads, no worker processes: cheap on 2 cores)."""
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        yield cluster.scheduler_address


@given(st.lists(st.integers(0, 60), max_size=12), st.booleans())
@settings(max_examples=30, deadline=None)
def test_serial_imap_is_the_plain_loop(jobs, ordered):
    """In this process: every job once, with its own index; ordered output is job order."""
    got = list(imap(math.factorial, jobs, workers=1, ordered=ordered))
    assert sorted(got) == sorted(enumerate(math.factorial(j) for j in jobs))
    assert map_jobs(math.factorial, jobs) == [math.factorial(j) for j in jobs]


def test_processes_and_dask_give_the_serial_results(dask_address):
    jobs = [5, 0, 30, 7, 12, 3]
    want = [math.factorial(j) for j in jobs]
    assert map_jobs(math.factorial, jobs, workers=2) == want
    assert map_jobs(math.factorial, jobs, workers=2, dask=dask_address) == want
    got = dict(imap(math.factorial, jobs, workers=2, dask=dask_address))  # completion order
    assert [got[i] for i in range(len(jobs))] == want


def test_a_job_error_reaches_the_caller(dask_address):
    """math.factorial(-1) raises ValueError: serially, from a pool and from Dask alike."""
    for kw in ({"workers": 1}, {"workers": 2}, {"workers": 1, "dask": dask_address}):
        with pytest.raises(ValueError, match="not defined for negative"):
            map_jobs(math.factorial, [3, -1, 4], **kw)


@pytest.mark.parametrize("bad", [0, -1, 1.5, "2", None])
def test_bad_workers_refused(bad):
    with pytest.raises(InputError, match="--workers must be a positive integer"):
        check_workers(bad)


def test_unreachable_scheduler_is_an_input_error(monkeypatch):
    """Nothing listens on port 1 of localhost: a one-line InputError naming the fix."""
    pytest.importorskip("distributed")
    monkeypatch.setattr(parallel, "CONNECT_TIMEOUT", 1.0)
    with pytest.raises(InputError, match="cannot reach the Dask scheduler.*--dask local"):
        map_jobs(math.factorial, [1, 2], dask="tcp://127.0.0.1:1")


def test_coverage_study_same_numbers_local_and_dask(dask_address):
    """A real study (two seeds of the PEM coverage harness, 10 s runs): every z-score,
    standard error and failure identical serially, in 2 processes and on Dask."""
    kw = {"seeds": 2, "duration": 10.0}
    serial = run_coverage(**kw)
    for other in (run_coverage(**kw, workers=2), run_coverage(**kw, dask=dask_address)):
        assert other.failed == serial.failed
        assert other.settings == serial.settings
        for q in serial.z:
            np.testing.assert_array_equal(other.z[q], serial.z[q])
            np.testing.assert_array_equal(other.stderr[q], serial.stderr[q])
        np.testing.assert_array_equal(other.mahalanobis, serial.mahalanobis)
    assert serial.n == 2  # the comparison is over real fits, not two failures


def test_moore_hubbard_runs_same_serial_and_dask(dask_address):
    """The reproduction's simulation pool (six 3 s nonlinear runs, one per rider x
    environment): every logged and true signal bit-identical serially and on Dask."""
    from bikeid.experiments.papers.moore_hubbard import make_runs

    serial = make_runs([4.0], 3.0)
    remote = make_runs([4.0], 3.0, workers=2, dask=dask_address)
    assert len(serial) == len(remote) == 6
    for a, b in zip(serial, remote, strict=True):
        assert a.meta["rider"] == b.meta["rider"] and a.meta["seed"] == b.meta["seed"]
        assert set(a.signals) == set(b.signals) and set(a.truth) == set(b.truth)
        for name in a.signals:
            np.testing.assert_array_equal(a[name], b[name])
        for name in a.truth:
            np.testing.assert_array_equal(a.true(name), b.true(name))
