"""Batch conversion of many captures: locally in parallel, resumably, or on a Dask cluster.

* :mod:`~leaffit_usd.batch.captures` - which captures (files, folders, manifests) and their names
* :mod:`~leaffit_usd.batch.task` - the one task function: one capture in its own process
* :mod:`~leaffit_usd.batch.worker` - that process (``pipeline.convert`` into a work folder)
* :mod:`~leaffit_usd.batch.state` - ``OUTDIR/batch.json``, atomic, resumable
* :mod:`~leaffit_usd.batch.executors` - local thread pool, dask.distributed
* :mod:`~leaffit_usd.batch.runner` - plan, execute, record, summarise (``run_batch``)

Layering: above ``pipeline`` (the worker runs it), below ``commands``.
"""
from leaffit_usd.batch.captures import Capture, collect_captures
from leaffit_usd.batch.runner import BatchOptions, BatchSummary, run_batch, summary_table
from leaffit_usd.batch.task import CaptureResult, CaptureTask, run_capture

__all__ = ["BatchOptions", "BatchSummary", "Capture", "CaptureResult", "CaptureTask",
           "collect_captures", "run_batch", "run_capture", "summary_table"]
