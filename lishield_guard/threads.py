"""One native thread per worker: parallel commands get their parallelism from processes."""

from __future__ import annotations

_LIMITER = None  # keeps the BLAS limit alive for the life of the process


def one_thread_per_worker() -> None:
    """Limit OpenCV's and the BLAS libraries' (numpy's, scipy's) thread pools to one thread.

    Call it once in each worker process (a pool's initializer) and in a service whose
    detections run side by side in threads. Each library otherwise starts a thread per core
    in every process, and their busy-waiting threads then fight over the same cores: on two
    cores, two detection processes ran 1.6-2.1x slower with default BLAS threading than with
    one thread each (same verdicts; ``benchmarks/evaluate.py --jobs 2`` on 60 images).
    """
    global _LIMITER
    import cv2
    import numpy  # noqa: F401 - load every BLAS library first: only loaded ones are limited
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits

    cv2.setNumThreads(1)
    if _LIMITER is None:
        _LIMITER = threadpool_limits(limits=1, user_api="blas")
