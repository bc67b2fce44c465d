"""Test-wide settings: BLAS pinned to one thread (as the command line does), because the
filters do many small matrix operations and a multithreaded BLAS on 2 shared cores only
adds synchronisation (the suite ran 2-7x slower without it)."""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
