"""One BLAS / OpenMP / OpenCV thread per vibro process, unless the caller says otherwise.

vibro's linear algebra is many small problems (a flight's least squares, a 3000 x 11 structure fit), and its
parallelism is processes: the node graph's eight nodes, ``--workers`` and campaign workers, pytest-xdist. A BLAS
thread pool the size of the machine in each process only adds threads that spin while they wait for work: a
3000 x 11 least squares took 1.14 ms of CPU with OpenBLAS's two threads and 0.195 ms with one, and ``vibro
analyze`` of a 3000-frame take 7.3 -> 4.7 CPU-s, the same results.json. :func:`one_blas_thread` must run before
numpy, scipy or OpenCV is imported (the libraries read the variables once, when they load); the node entry points
(:mod:`vibro_ros.entry`) and the ``vibro`` command (:mod:`vibro_app.cli`) call it first. Imports nothing heavy.
"""

from __future__ import annotations

import os
from typing import MutableMapping

#: the variables the BLAS libraries, OpenMP and OpenCV read for their thread counts
THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")


def one_blas_thread(environ: MutableMapping[str, str] = os.environ) -> dict[str, str]:
    """Set each of :data:`THREAD_VARIABLES` to 1 in ``environ`` where it is not set already (a value the caller
    set wins, e.g. ``OPENBLAS_NUM_THREADS=8 vibro analyze ...``); returns the variables as they now are."""
    for name in THREAD_VARIABLES:
        environ.setdefault(name, "1")
    return {name: environ[name] for name in THREAD_VARIABLES}
