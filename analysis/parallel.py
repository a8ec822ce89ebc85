"""How the analysis uses the CPU cores: worker processes for independent fits, one BLAS
thread inside each.

The diagnosis fits every catalogue effect as a candidate, each on its own: work that splits
over cores with nothing to share but the data. The workers are forked, so they inherit the
data (no copy is sent); each task sends back one small result. Where ``fork`` is not
available, or the work is small, everything runs in this process, in order. Results are the
same either way: every task is deterministic and runs alone.

BLAS threads do not pay here: the fits' linear algebra is one factorization of a tall, thin
Jacobian per least-squares step, and OpenBLAS's threads spent more time handing the work
around than doing it, and in forked workers each worker's BLAS threads crowd the others'. So
fits run under :func:`one_blas_thread` (the figures: docs/decisions.md).
"""
from __future__ import annotations

import functools
import multiprocessing
import os
from typing import Any, Callable, Iterable, Iterator, TypeVar

from threadpoolctl import threadpool_limits

T = TypeVar("T")
R = TypeVar("R")

#: work (the estimated seconds of all the tasks on one core) below which forking is not worth
#: it: a worker costs ~10 ms to fork; a candidate's screening fit is ~100 evaluations of the
#: model (0.5 s on 100 k samples of the base model, 2 s with a force-dependent effect)
AUTO_MIN_WORK_S = 3.0
#: at most this many workers when chosen automatically
AUTO_MAX_WORKERS = 8

_shared: Any = None


def one_blas_thread(fn: Callable[..., R]) -> Callable[..., R]:
    """Run ``fn`` with every loaded BLAS library (numpy's, scipy's) limited to one thread,
    restored afterwards (see the module docstring for why)."""
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)
    return wrapper


def workers_for(tasks: int, work_s: float, jobs: int | None = None) -> int:
    """How many worker processes to use: ``jobs`` if given (1: none), else one per CPU this
    process may run on (at most :data:`AUTO_MAX_WORKERS`) if ``work_s`` (the tasks' estimated
    seconds on one core) is at least :data:`AUTO_MIN_WORK_S`, never more than ``tasks``."""
    if "fork" not in multiprocessing.get_all_start_methods():
        return 1
    if jobs is None:
        if work_s < AUTO_MIN_WORK_S:
            return 1
        try:
            cpus = len(os.sched_getaffinity(0))
        except (AttributeError, OSError):
            cpus = os.cpu_count() or 1
        jobs = min(cpus, AUTO_MAX_WORKERS)
    return max(1, min(jobs, tasks))


def _call(task):
    fn, item = task
    return item, fn(_shared, item)


def run_each(fn: Callable[[Any, T], R], items: Iterable[T], shared: Any,
             workers: int) -> Iterator[tuple[T, R]]:
    """``(item, fn(shared, item))`` for every item, as each finishes (in order when
    ``workers`` is 1). ``fn`` must be a module-level function; ``shared`` reaches the workers
    by fork, not by pickling. An exception in a task is raised here."""
    items = list(items)
    if workers <= 1 or len(items) <= 1:
        for item in items:
            yield item, fn(shared, item)
        return
    global _shared
    _shared = shared
    try:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            yield from pool.imap_unordered(_call, [(fn, item) for item in items])
    finally:
        _shared = None
