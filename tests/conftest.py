"""Test-wide settings: BLAS pinned to one thread (as the command line does), because the
filters do many small matrix operations and a multithreaded BLAS on 2 shared cores only
adds synchronisation (the suite ran 2-7x slower without it)."""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def compiled_kernels(loader, what: str):
    """The module of numba kernels ``loader()`` gives (e.g. ``hybrid.shift_kernels``), for
    a test of a compiled path: skipped without numba or with ``UAVEST_NUMBA=0`` (.ci/run's
    second pass: the numpy paths only), failed if numba is there and the kernels were
    refused (their self-check disagreed or they did not compile: see the log)."""
    import pytest

    pytest.importorskip("numba", reason="numba not installed (the optional uavest[fast])")
    if os.environ.get("UAVEST_NUMBA") == "0":
        pytest.skip("UAVEST_NUMBA=0: the numpy paths only (.ci/run's second pass)")
    nb = loader()
    if not nb:
        pytest.fail(f"numba is installed but the {what} were refused (see the log)")
    return nb
