"""Where the chunks of a campaign run: in this process, local processes, or Dask.

Every executor has the same shape: ``run_X(execute, make_chunks, finished, ...)``.

* ``execute(chunk) -> rows``: runs a chunk (a list of run indices) and returns its rows;
  picklable (the runner passes ``functools.partial(execute_chunk, spec)``).
* ``make_chunks(n_parallel) -> [chunk, ...]``: the pending runs cut into chunks, given
  how many run at once (the executor knows: processes, or the cluster's threads).
* ``finished(rows)``: called in this process as each chunk finishes, in the order they
  finish (the runner writes a part file there).

An exception (Ctrl-C included) stops the executor without waiting for running chunks;
what ``finished`` saw is kept. Executors: ``"serial"`` (this process; for debugging),
``"local"`` (a ``concurrent.futures`` process pool, forked where the platform can),
``"dask"`` (``dask.distributed``: a ``LocalCluster`` started here when ``scheduler`` is
None, else the cluster at ``scheduler``; chunks lost with a dead worker are rescheduled,
up to ``retries`` times per chunk).
"""

from __future__ import annotations

import os
from collections.abc import Callable

from gnomon.errors import InputError

__all__ = ["EXECUTORS", "run_chunks", "run_serial", "run_local", "run_dask", "default_workers"]

EXECUTORS = ("local", "dask", "serial")

Execute = Callable[[list[int]], list[dict]]
MakeChunks = Callable[[int], list[list[int]]]
Finished = Callable[[list[dict]], None]


def default_workers(workers: int | None) -> int:
    """``workers``, or this machine's CPU count when None."""
    return int(workers) if workers else (os.cpu_count() or 1)


def run_serial(execute: Execute, make_chunks: MakeChunks, finished: Finished) -> None:
    """Every chunk in this process, one after the other."""
    for chunk in make_chunks(1):
        finished(execute(chunk))


def run_local(execute: Execute, make_chunks: MakeChunks, finished: Finished,
              workers: int | None = None) -> None:
    """The chunks on a pool of ``workers`` processes of this machine (default: all cores)."""
    import concurrent.futures as cf
    import multiprocessing as mp

    n = default_workers(workers)
    ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
    pool = cf.ProcessPoolExecutor(max_workers=n, mp_context=ctx)
    try:
        futs = [pool.submit(execute, c) for c in make_chunks(n)]
        for f in cf.as_completed(futs):
            finished(f.result())
    except BaseException:
        # Ctrl-C / error: keep what is written, do not wait for the running chunks
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()


def run_dask(execute: Execute, make_chunks: MakeChunks, finished: Finished,
             workers: int | None = None, scheduler: str | None = None,
             retries: int = 3) -> None:
    """The chunks on a Dask cluster: the one at ``scheduler`` (``tcp://host:port``), or a
    ``LocalCluster`` of ``workers`` single-threaded processes for the duration of the call.
    ``InputError`` if Dask is not installed or the scheduler cannot be reached."""
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        raise InputError("the dask executor needs 'dask[distributed]' (pip install "
                         "'gnomon[dask]')", field="executor") from None
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=default_workers(workers), threads_per_worker=1,
                               processes=True, dashboard_address=None)
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout=30)
        except OSError as err:
            raise InputError(f"cannot reach the Dask scheduler: {err}",
                             field="scheduler") from None
    try:
        n_parallel = max(1, sum(client.nthreads().values()))
        futs = [client.submit(execute, c, pure=False, retries=retries)
                for c in make_chunks(n_parallel)]
        try:
            for f in as_completed(futs):
                finished(f.result())
        except BaseException:
            client.cancel(futs)
            raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_chunks(executor: str, execute: Execute, make_chunks: MakeChunks, finished: Finished,
               *, workers: int | None = None, scheduler: str | None = None,
               retries: int = 3) -> None:
    """Dispatch to the executor named ``executor`` (one of :data:`EXECUTORS`)."""
    if executor == "serial":
        run_serial(execute, make_chunks, finished)
    elif executor == "local":
        run_local(execute, make_chunks, finished, workers)
    elif executor == "dask":
        run_dask(execute, make_chunks, finished, workers, scheduler, retries)
    else:
        raise InputError(f"unknown executor {executor!r}; use local, dask or serial",
                         field="executor")
