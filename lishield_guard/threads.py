"""Native thread pools (BLAS, OpenCV) held to what a command asks for: one per worker by default.

Each native library otherwise starts a thread per core in every process, and their busy-waiting
threads then fight over the same cores as the detection itself and as any other job on the
machine: on two cores, two detection processes ran 1.6-2.1x slower with default BLAS threading
than with one thread each (same verdicts; ``benchmarks/evaluate.py --jobs 2`` on 60 images),
and one ``detect`` of the demo photo measured 394-690 ms instead of 90-120 ms beside another
CPU job (issue 41).

- `pin_native_threads` limits the process for good: the command line (``detect --threads``),
  pool workers (`one_thread_per_worker`) and the service call it once at start;
- `native_threads` limits them for the duration of one call and then restores what was there:
  the Python API (`lishield_guard.detect`, `lishield_guard.video.detect_media`) runs inside it,
  so a program's first call is as fast as the command line's without its own numpy changing
  for good. It honours a process-wide pin (`pinned_threads`).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["native_threads", "one_thread_per_worker", "pin_native_threads", "pinned_threads"]

_LIMITER = None  # keeps a process-wide BLAS limit alive for the life of the process
_PINNED: int | None = None  # the process-wide limit, once set
_CONTROLLER = None  # threadpoolctl's view of the loaded BLAS libraries (built once)
_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_SCOPE_LOCK = threading.Lock()
_SCOPE: dict = {"depth": 0, "restore": None, "n": None}


_BLAS_MODULES = ("numpy", "cv2", "scipy.linalg", "sklearn", "torch")  # each brings its own


def _controller():
    """threadpoolctl's view of the BLAS libraries loaded now (numpy's and OpenCV's OpenBLAS
    are loaded first: the caller is about to use them). It is built again when a module that
    brings another BLAS library has been imported since (scipy.linalg, for one), and is
    otherwise reused (building it costs about 4 ms)."""
    global _CONTROLLER
    import sys

    import cv2  # noqa: F401 - its bundled OpenBLAS
    import numpy  # noqa: F401

    loaded = tuple(name in sys.modules for name in _BLAS_MODULES)
    if _CONTROLLER is None or _CONTROLLER[0] != loaded:
        from threadpoolctl import ThreadpoolController

        _CONTROLLER = (loaded, ThreadpoolController().select(user_api="blas"))
    return _CONTROLLER[1]


def _check(n_threads: int) -> int:
    if isinstance(n_threads, bool) or not isinstance(n_threads, int) or n_threads < 1:
        from lishield_guard.errors import ConfigError

        raise ConfigError(f"need n_threads >= 1 native threads, got n_threads={n_threads!r}")
    return n_threads


def pin_native_threads(n_threads: int = 1) -> None:
    """Limit OpenCV's and every loaded BLAS library's thread pool to ``n_threads``, for good.

    Call it once at the start of a command, in each worker process (a pool's initializer)
    and in a service whose detections run side by side in threads. Calling it again with
    another count changes the limit. The BLAS libraries loaded now are limited with
    threadpoolctl, those loaded later (and child processes) by ``OPENBLAS_NUM_THREADS``,
    ``OMP_NUM_THREADS`` and ``MKL_NUM_THREADS``, which are set to ``n_threads``.

    Parameters
    ----------
    n_threads : int
        Native threads per library, >= 1.

    Raises
    ------
    ConfigError
        When ``n_threads`` is not an integer >= 1.
    """
    global _LIMITER, _PINNED
    import os

    n_threads = _check(n_threads)
    for var in _THREAD_VARIABLES:  # BLAS libraries loaded later (and child processes)
        os.environ[var] = str(n_threads)
    import cv2

    controller = _controller()
    cv2.setNumThreads(n_threads)
    if _PINNED != n_threads or _LIMITER is None or _LIMITER[0] is not controller:
        _LIMITER = (controller, controller.limit(limits=n_threads))
        _PINNED = n_threads


def one_thread_per_worker() -> None:
    """`pin_native_threads` (1): one BLAS and one OpenCV thread in this process."""
    pin_native_threads(1)


def pinned_threads() -> int | None:
    """The process-wide limit `pin_native_threads` set, or None when none was set."""
    return _PINNED


@contextmanager
def native_threads(n_threads: int | None = None) -> Iterator[int]:
    """Run a block with OpenCV and BLAS limited to ``n_threads``; restore them afterwards.

    Nested and concurrent blocks share one limit: the first to enter sets it and the last to
    leave restores what the libraries had before (so threads of a program running several
    detections at once never see each other's restore). Entering costs about 20 us.

    Parameters
    ----------
    n_threads : int, optional
        Threads per library; default the process-wide pin (`pinned_threads`), else 1.

    Yields
    ------
    int
        The limit in force.

    Examples
    --------
    >>> with native_threads(1) as n:
    ...     n
    1
    """
    n = _check(n_threads if n_threads is not None else (_PINNED or 1))
    import cv2

    controller = _controller()
    with _SCOPE_LOCK:
        if _SCOPE["depth"] == 0:
            _SCOPE["restore"] = (cv2.getNumThreads(), controller.limit(limits=n))
            _SCOPE["n"] = n
            cv2.setNumThreads(n)
        _SCOPE["depth"] += 1
        in_force = _SCOPE["n"]
    try:
        yield in_force
    finally:
        with _SCOPE_LOCK:
            _SCOPE["depth"] -= 1
            if _SCOPE["depth"] == 0:
                cv2_threads, limiter = _SCOPE["restore"]
                _SCOPE["restore"] = None
                limiter.restore_original_limits()
                cv2.setNumThreads(cv2_threads)
