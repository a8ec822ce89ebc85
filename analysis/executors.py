"""Where a rig's per-channel work runs: a :class:`concurrent.futures.Executor`.

Identifying a rig of N channels is N diagnoses, independent once the coupling is known
(:mod:`analysis.diagnosis.rig`). The analysis takes any ``Executor`` and only ``submit``\\ s
module-level functions with picklable arguments, so it runs the same

* in this process, in order (:class:`InlineExecutor`; ``--jobs 1``);
* in a local process pool (:func:`local_executor`; the default, one worker per CPU up to
  :data:`~analysis.parallel.AUTO_MAX_WORKERS`, ``--jobs N``);
* on a dask cluster: ``distributed.Client(address).get_executor()`` (:func:`rig_executor` with
  ``scheduler=ADDRESS``; ``pip install 'hydrostand[cluster]'``), for a rig one machine cannot
  identify in time. No task distribution of our own: the pool and the cluster's scheduler do it.

A task carries what its worker needs besides the installed project: the data, and the user's
plug-in effects as their sources (:func:`plant.plugins.shippable_plugins`, loaded in the worker
by :func:`plant.plugins.load_shipped`): a cluster's worker runs in another process, perhaps on
another machine, where the client's loaded modules are not. Each worker fits with one BLAS
thread and no worker processes of its own (the candidate fits inside a channel's diagnosis run
in order there: the channels are the parallel work).
"""
from __future__ import annotations

import contextlib
import multiprocessing
import os
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from typing import Any, Callable, Iterator

from core.errors import ParameterError

from .parallel import AUTO_MAX_WORKERS

#: how long to wait for a dask scheduler to answer, s
CONNECT_TIMEOUT_S = 10.0


class InlineExecutor(Executor):
    """Runs each call when it is submitted, in this process (the executor of ``--jobs 1``):
    the same results as a pool, in order, with a traceback where it happened."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller through the future
            fut.set_exception(exc)
        return fut


def cpus() -> int:
    """The CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def local_executor(jobs: int | None = None, tasks: int | None = None) -> Executor:
    """A local pool of ``jobs`` worker processes (default one per CPU, at most
    :data:`AUTO_MAX_WORKERS`, never more than ``tasks``); ``jobs`` 1: :class:`InlineExecutor`.
    Workers are forked where the platform can (they start at once and inherit the loaded
    modules), spawned elsewhere (the shipped plug-ins make that work too)."""
    if jobs is not None and jobs < 1:
        raise ParameterError(f"--jobs {jobs} is out of range: give 1 or more")
    n = jobs if jobs is not None else min(cpus(), AUTO_MAX_WORKERS)
    if tasks is not None:
        n = min(n, max(1, tasks))
    if n <= 1:
        return InlineExecutor()
    method = "fork" if "fork" in multiprocessing.get_all_start_methods() else "spawn"
    return ProcessPoolExecutor(max_workers=n, mp_context=multiprocessing.get_context(method))


@contextlib.contextmanager
def rig_executor(jobs: int | None = None, scheduler: str | None = None,
                 tasks: int | None = None) -> Iterator[Executor]:
    """The executor a rig's analysis runs on, closed afterwards: a dask cluster's when
    ``scheduler`` (its address, ``tcp://host:8786``) is given, else :func:`local_executor`."""
    if scheduler is None:
        ex = local_executor(jobs, tasks)
        with ex:
            yield ex
        return
    if jobs is not None:
        raise ParameterError("--jobs and --scheduler: give one (the cluster's workers are the "
                             "scheduler's to count)")
    try:
        from distributed import Client
    except ImportError:
        raise ParameterError(f"--scheduler {scheduler}: dask.distributed is not installed: pip "
                             "install 'hydrostand[cluster]' (or leave --scheduler out to use "
                             "this machine's cores)") from None
    try:
        client = Client(scheduler, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ParameterError(f"--scheduler {scheduler}: cannot reach a dask scheduler there "
                             f"({type(exc).__name__}: {exc}); start one (dask scheduler, then "
                             "dask worker ADDRESS on each machine) or check the address") from None
    try:
        yield client.get_executor(pure=False)
    finally:
        client.close()
