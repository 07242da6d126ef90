"""Executors: run :func:`leaffit_usd.batch.task.run_capture` for many tasks, report each result.

Both call ``on_result(CaptureResult)`` in the calling thread as tasks finish, so the batch state
has one writer. On an exception in the caller (SIGTERM, Ctrl-C, raised by the signal handler
while it waits) they ask the running tasks to stop, report what comes back (status
"cancelled"), and re-raise.

* ``local``: a thread pool of ``jobs`` threads on this machine, each watching one worker process.
* ``dask``: ``dask.distributed`` (extra ``[dask]``): a scheduler address, or a ``LocalCluster``
  of ``jobs`` single-thread workers. The tasks run on the workers, which start the worker
  processes there and write the outputs to the (shared) output folder; cancellation goes
  through a ``distributed.Event`` the tasks poll.
"""
from __future__ import annotations

import logging
import threading
import time
import traceback
import uuid
from concurrent.futures import ThreadPoolExecutor, as_completed
from typing import Callable

from leaffit_usd.batch.task import CaptureResult, CaptureTask, run_capture
from leaffit_usd.errors import UserError

log = logging.getLogger("leaffit_usd")


def _safe_run(task: CaptureTask, should_stop=None) -> CaptureResult:
    """run_capture, with an error of the batch machinery itself (disk full...) as a failure."""
    try:
        return run_capture(task, should_stop)
    except Exception as e:  # noqa: BLE001 - one capture's problem, the batch goes on
        return CaptureResult(task.name, "failed", f"batch error: {type(e).__name__}: {e}".splitlines()[0],
                             host="", report={"traceback": traceback.format_exc()})


def run_local(tasks: list[CaptureTask], jobs: int, on_result: Callable[[CaptureResult], None]) -> None:
    """Run the tasks on a pool of ``jobs`` threads (each one watches one worker process)."""
    stop = threading.Event()
    pool = ThreadPoolExecutor(max_workers=max(1, jobs), thread_name_prefix="leaffit-batch")
    futures = {pool.submit(_safe_run, t, stop.is_set): t for t in tasks}
    done = set()
    try:
        for f in as_completed(futures):
            done.add(f)
            on_result(f.result())
    except BaseException:
        stop.set()
        for f in futures:
            f.cancel()
        for f in futures:
            if f not in done and not f.cancelled():
                try:
                    on_result(f.result())
                except Exception:  # noqa: BLE001
                    pass
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def dask_task(task: CaptureTask, stop_event: str) -> CaptureResult:
    """The Dask task: run_capture on a worker, cancelled through the named distributed Event."""
    from distributed import Event

    ev = Event(stop_event)
    last = [0.0, False]

    def should_stop() -> bool:           # at most one scheduler round trip per second
        now = time.monotonic()
        if now - last[0] > 1.0:
            last[0] = now
            try:
                last[1] = ev.is_set()
            except Exception:  # noqa: BLE001 - scheduler gone: stop
                last[1] = True
        return last[1]

    return _safe_run(task, should_stop)


def dask_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("distributed") is not None


def run_dask(tasks: list[CaptureTask], jobs: int, on_result: Callable[[CaptureResult], None],
             scheduler: str | None = None) -> None:
    """Run the tasks on a Dask cluster (``scheduler`` address) or a LocalCluster of ``jobs``
    single-thread workers."""
    if not dask_available():
        raise UserError("--executor dask needs dask.distributed: pip install 'leaffit-usd[dask]'")
    from distributed import Client, Event, LocalCluster
    from distributed import as_completed as dask_as_completed

    cluster = None
    try:
        if scheduler:
            try:
                client = Client(scheduler, timeout="20s")
            except (OSError, TimeoutError) as e:
                raise UserError(f"--scheduler {scheduler}: cannot connect ({type(e).__name__}: {e})") from None
        else:
            # in-process workers are enough: every capture runs in its own worker process anyway
            cluster = LocalCluster(n_workers=max(1, jobs), threads_per_worker=1, processes=False,
                                   dashboard_address=None, silence_logs=logging.ERROR)
            client = Client(cluster)
    except BaseException:
        if cluster is not None:
            cluster.close()
        raise
    run_id = uuid.uuid4().hex[:12]
    ev_name = f"leaffit-batch-stop-{run_id}"
    ev = Event(ev_name, client=client)
    by_key = {}
    futures = []
    for t in tasks:
        f = client.submit(dask_task, t, ev_name, key=f"leaffit-{t.name}-{run_id}", pure=False)
        by_key[f.key] = t
        futures.append(f)
    done = set()

    def result_of(f) -> CaptureResult:
        try:
            return f.result()
        except Exception as e:  # noqa: BLE001 - a lost worker, a task error
            t = by_key[f.key]
            return CaptureResult(t.name, "failed", f"dask: {type(e).__name__}: {e}".splitlines()[0])

    try:
        for f in dask_as_completed(futures):
            done.add(f.key)
            on_result(result_of(f))
    except BaseException:
        # running tasks see the event within ~1 s, kill their worker process and clean up;
        # queued ones are dropped
        ev.set()
        running = _running_keys(client)
        for f in futures:
            if f.key not in done and f.key not in running:
                f.cancel()
        deadline = time.monotonic() + 60
        for f in futures:
            if f.key in done or f.key not in running:
                continue
            try:
                f.result(timeout=max(1.0, deadline - time.monotonic()))
                on_result(result_of(f))
            except Exception:  # noqa: BLE001
                pass
        raise
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _running_keys(client) -> set:
    """Keys of the tasks the workers are processing now (they must be stopped, not dropped)."""
    try:
        return {k for keys in client.processing().values() for k in keys}
    except Exception:  # noqa: BLE001 - scheduler unreachable: nothing to wait for
        return set()
