"""One pool runner for every batch tool: workers set up once, results as they arrive.

`run_pool` runs ``fn`` on every item's work in worker processes (or in this process for one
job, with one native thread while each item runs). Each worker is initialised once: one BLAS
thread, a watch on the parent (a killed batch leaves no worker behind) and the run's
``state`` (a config, a cache folder), which ``fn`` reads with `worker_state`. At most
``max_in_flight`` tasks are submitted at once, so a lazy item iterator is consumed lazily; a
crashed worker fails only the tasks it took down (they come back as `WorkerCrashed`) and a
fresh pool carries on; on an exception or Ctrl-C in the consumer the pending tasks are
cancelled and the workers shut down.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

from lishield_guard.threads import native_threads, one_thread_per_worker

__all__ = ["WorkerCrashed", "progress_bar", "run_pool", "worker_state"]

T = TypeVar("T")

_STATE: dict[str, Any] = {}


class WorkerCrashed(RuntimeError):
    """A worker process died while it held this task (or another one in flight)."""


def worker_state() -> Any:
    """The ``state`` given to `run_pool`, inside a task."""
    if "state" not in _STATE:
        raise RuntimeError("worker not initialised (call fn through run_pool)")
    return _STATE["state"]


def _watch_parent(pid: int, interval_s: float = 0.5) -> None:
    """Exit this worker as soon as process ``pid`` (the batch) is gone, even after SIGKILL.

    Pool workers are children of the forkserver, not of the batch, so they would outlive a
    killed batch; a daemon thread waits on a pidfd of the batch (or polls it) and exits.
    """
    def watch() -> None:
        try:
            import select

            fd = os.pidfd_open(pid)
            select.select([fd], [], [])
        except (AttributeError, OSError):
            while True:
                try:
                    os.kill(pid, 0)
                except ProcessLookupError:
                    break
                except PermissionError:
                    pass
                time.sleep(interval_s)
        os._exit(1)

    threading.Thread(target=watch, name="lishield-parent-watch", daemon=True).start()


def _init_worker(state: Any, parent_pid: int | None, preload: tuple[str, ...]) -> None:
    _STATE["state"] = state
    if parent_pid is not None:
        _watch_parent(parent_pid)
    one_thread_per_worker()
    import importlib

    for name in preload:  # warm the imports once per worker
        importlib.import_module(name)


def _new_pool(jobs: int, state: Any, preload: tuple[str, ...]):
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(["lishield_guard.batch.pool", *preload])
    return ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=_init_worker,
                               initargs=(state, os.getpid(), preload))


def run_pool(fn: Callable[[Any], Any], items: Iterable[T], *, jobs: int, state: Any = None,
             work: Callable[[T], Any] = lambda item: item, ordered: bool = False,
             max_in_flight: int | None = None, preload: tuple[str, ...] = (),
             in_process: bool | None = None) -> Iterator[tuple[T, Any]]:
    """Run ``fn(work(item))`` for every item in worker processes; yield ``(item, result)``.

    Parameters
    ----------
    fn : callable
        Module-level (picklable) function of one argument; reads `worker_state` for the rest.
    items : iterable
        Consumed lazily: at most ``max_in_flight`` are submitted and unfinished at once.
    jobs : int
        Worker processes (>= 1).
    state : picklable, optional
        Sent once to every worker (a config, grids, a cache folder).
    work : callable, optional
        ``work(item)`` is what ``fn`` receives; None means nothing to run, and the item is
        yielded at once with result None (an input recorded without work).
    ordered : bool
        Yield in input order (results are held until their turn); default: as they finish.
    max_in_flight : int, optional
        Submitted but unfinished tasks; default ``4 * jobs``.
    preload : tuple of str
        Modules imported once per worker (and preloaded by the forkserver).
    in_process : bool, optional
        Run in this process, one item at a time; default when ``jobs == 1`` and
        ``max_in_flight`` is not given.

    Yields
    ------
    (item, result)
        ``result`` is ``fn``'s return value, or a `WorkerCrashed` instance when the worker
        running it died; exceptions ``fn`` raises propagate.
    """
    jobs = max(1, int(jobs))
    if in_process if in_process is not None else (jobs == 1 and max_in_flight is None):
        _STATE["state"] = state
        for item in items:
            w = work(item)
            if w is None:
                yield item, None
                continue
            with native_threads(1):  # this process is the one worker
                result = fn(w)
            yield item, result
        return
    yield from _run_processes(fn, items, jobs=jobs, state=state, work=work, ordered=ordered,
                              limit=max_in_flight or 4 * jobs, preload=preload)


def _run_processes(fn, items, *, jobs, state, work, ordered, limit, preload):
    from concurrent.futures import FIRST_COMPLETED, wait
    from concurrent.futures.process import BrokenProcessPool

    pool = _new_pool(jobs, state, preload)
    pending: dict[Any, int] = {}  # future -> input index
    held: dict[int, tuple[Any, Any]] = {}  # finished, waiting for their turn (ordered)
    order: dict[int, Any] = {}  # input index -> item
    next_out = 0

    def ready() -> Iterator[tuple[Any, Any]]:
        nonlocal next_out
        while next_out in held:
            yield held.pop(next_out)
            next_out += 1

    def finish(i: int, result: Any) -> Iterator[tuple[Any, Any]]:
        item = order.pop(i)
        if ordered:
            held[i] = (item, result)
            yield from ready()
        else:
            yield item, result

    def drain(block_until: int) -> Iterator[tuple[Any, Any]]:
        nonlocal pool
        while len(pending) > block_until:
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            broken = False
            for fut in sorted(done, key=pending.get):
                i = pending.pop(fut)
                try:
                    result = fut.result()
                except BrokenProcessPool:
                    broken = True
                    result = WorkerCrashed("worker process died while running this input "
                                           "(or another in flight)")
                yield from finish(i, result)
            if broken:  # every other in-flight future fails too; then start a fresh pool
                pool.shutdown(wait=False, cancel_futures=True)
                pool = _new_pool(jobs, state, preload)

    try:
        for i, item in enumerate(items):
            order[i] = item
            w = work(item)
            if w is None:
                yield from finish(i, None)
                continue
            yield from drain(limit - 1)
            try:
                fut = pool.submit(fn, w)
            except BrokenProcessPool:
                pool = _new_pool(jobs, state, preload)
                fut = pool.submit(fn, w)
            pending[fut] = i
        yield from drain(0)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def progress_bar(desc: str | None = None, *, total: int | None = None, enabled: bool = True,
                 **kw: Any):
    """A tqdm bar on stderr counting images (disabled: the same object, drawing nothing)."""
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="img", file=sys.stderr, disable=not enabled,
                dynamic_ncols=True, **kw)
