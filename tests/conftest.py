"""Test-suite settings.

Hypothesis runs derandomized by default (the same examples on every run), so that CI on a
clean clone gives the same verdict as the run before the commit; explore new examples with
``HYPOTHESIS_PROFILE=explore python -m pytest`` (random seeds, as hypothesis does by default)
and add any failure it finds as an ``@example``.
"""

import os

# One BLAS thread per test worker, set before numpy loads OpenBLAS: pytest-xdist runs one
# worker per core, and bikeid's 4x4-10x10 products gain nothing from more threads, which
# only spin against the other worker (the CLI and the fitting API limit it the same way).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from hypothesis import settings  # noqa: E402

settings.register_profile("bikeid", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "bikeid"))


def pytest_collection_modifyitems(config, items):
    """Test files with the most ``slow`` tests first (then the most tests), each file's
    tests in their own order.  With ``--dist loadfile --no-loadscope-reorder`` the workers
    take files in this order, so the long files start first and the short ones fill the end
    (longest first: the workers finish together instead of one waiting on a late long file).
    """
    files: dict[str, list] = {}
    for item in items:
        files.setdefault(item.nodeid.split("::", 1)[0], []).append(item)

    def weight(name: str) -> tuple[int, int]:
        tests = files[name]
        return (-sum(1 for t in tests if t.get_closest_marker("slow")), -len(tests))

    items[:] = [t for name in sorted(files, key=weight) for t in files[name]]
