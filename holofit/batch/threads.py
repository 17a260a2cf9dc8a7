"""One BLAS / OpenMP / FFT / numba thread per worker process.

Frames run in parallel as processes; letting every process also start a thread per core
oversubscribes the machine and makes runs slower and their floating-point results depend on
the thread count. The thread pools of these libraries read their size from the environment
when they load, so the variables must be set before a worker imports numpy: the batch runner
sets them around the creation of its worker processes (which inherit them) and restores the
caller's values afterwards.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

__all__ = ["THREAD_VARIABLES", "limit_threads_in_this_process", "single_thread_environment"]

#: environment variables that size the thread pools of BLAS, OpenMP, numexpr, numba, ...
THREAD_VARIABLES: tuple[str, ...] = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "BLIS_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "NUMBA_NUM_THREADS",
)


def single_thread_variables() -> dict[str, str]:
    """``{name: "1"}`` for every variable in :data:`THREAD_VARIABLES`."""
    return dict.fromkeys(THREAD_VARIABLES, "1")


@contextlib.contextmanager
def single_thread_environment() -> Iterator[None]:
    """Set every variable of :data:`THREAD_VARIABLES` to 1 inside the block, then restore."""
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    os.environ.update(single_thread_variables())
    try:
        yield
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def limit_threads_in_this_process() -> None:
    """Best effort for a process whose libraries are already loaded (a Dask worker): set the
    variables for anything that loads later. Thread pools that already started keep their
    size; Dask's nanny sets OMP/MKL/OpenBLAS to 1 before it starts a worker, and holofit's own
    compiled kernels are single-threaded."""
    os.environ.update(single_thread_variables())
