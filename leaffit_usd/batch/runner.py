"""``run_batch``: plan (skip what is complete), execute, record, summarise."""
from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import shutil
import signal
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from leaffit_usd.batch.captures import Capture
from leaffit_usd.batch.state import BatchState, batch_lock, now_iso, options_json, options_sha256
from leaffit_usd.batch.task import LOG_NAME, WORK_PREFIX, CaptureResult, CaptureTask
from leaffit_usd.errors import ParameterError

log = logging.getLogger("leaffit_usd")

STAGE_FORMATS = ("usda", "usdc", "usdz")


@dataclass
class BatchOptions:
    """Options of :func:`run_batch`.

    convert : ``pipeline.ConvertOptions`` shared by every capture (a manifest row overrides
        fields of it for its capture)
    stage_format : "usda" | "usdc" | "usdz": each stage is ``OUTDIR/NAME/NAME.<stage_format>``
    jobs : captures converted at once (None: cores / threads)
    threads : torch / BLAS threads per capture (None: cores / jobs, at least 1)
    timeout : seconds per capture before it is killed and recorded as failed (None: no limit)
    max_memory : bytes of resident memory per capture before it is killed (None: no limit)
    force : convert again captures whose output is complete and up to date
    executor : "local" | "dask"; scheduler : a Dask scheduler address (None: a LocalCluster)
    progress : show the progress bar and one line per finished capture on stderr
    """

    convert: object = None
    stage_format: str = "usda"
    jobs: int | None = None
    threads: int | None = None
    timeout: float | None = None
    max_memory: int | None = None
    force: bool = False
    executor: str = "local"
    scheduler: str | None = None
    progress: bool = True


@dataclass
class BatchSummary:
    """What one ``run_batch`` did. rows : one dict per capture of this run (name, status
    "done" | "skipped" | "failed" | "cancelled", leaves, gaussians, seconds, error, stage);
    exit_code : 0 all done or skipped, 1 any failed or cancelled."""

    rows: list = field(default_factory=list)
    exit_code: int = 0
    seconds: float = 0.0
    jobs: int = 1
    threads: int = 1
    interrupted: str = ""

    def count(self, status: str) -> int:
        return sum(r["status"] == status for r in self.rows)


def cpu_count() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def plan_parallelism(n_tasks: int, jobs: int | None, threads: int | None,
                     cores: int | None = None) -> tuple[int, int]:
    """(jobs, threads per job) so that jobs x threads <= cores unless both are given.

    Neither given: one thread per job, one job per core; then spare cores (fewer captures than
    cores) go to the jobs' threads. Only jobs given: threads = cores // jobs. Only threads
    given: jobs = cores // threads. Jobs never exceed the number of captures."""
    cores = cores or cpu_count()
    if jobs is not None and jobs < 1:
        raise ParameterError("--jobs", "an integer >= 1", jobs)
    if threads is not None and threads < 1:
        raise ParameterError("--threads", "an integer >= 1", threads)
    j = jobs if jobs is not None else max(1, cores // (threads or 1))
    j = max(1, min(j, max(n_tasks, 1)))
    t = threads if threads is not None else max(1, cores // j)
    return j, t


def _clean_leftovers(outdir: Path) -> None:
    """Remove work folders a killed batch left behind (their outputs were never moved into place)."""
    if not outdir.is_dir():
        return
    for cdir in outdir.iterdir():
        if cdir.is_dir():
            for w in cdir.glob(f"{WORK_PREFIX}*"):
                shutil.rmtree(w, ignore_errors=True)


class _Interrupted(BaseException):
    def __init__(self, signum):
        super().__init__(signum)
        self.signum = signum


def _fmt_s(s: float) -> str:
    return f"{s:.1f}"


@dataclass
class _Planned:
    """One capture of the batch: its options (the base with the manifest's overrides), their JSON
    and sha256, the input's sha256, and ``kept``: "done" (complete and up to date), "failed" (a
    bad-input failure that would fail again) or "" (convert)."""

    capture: Capture
    options: object
    odict: dict
    osha: str
    isha: str
    kept: str


@dataclass
class _Run:
    """What one ``run_batch`` works on: the state file, one summary row per capture (also by
    name), the tasks to convert, this run's record in the state, the progress bar (or None)."""

    outdir: Path
    state: BatchState
    rows: list = field(default_factory=list)
    by_name: dict = field(default_factory=dict)
    tasks: list = field(default_factory=list)
    run_info: dict = field(default_factory=dict)
    bar: object = None


def run_batch(captures: list[Capture], outdir, options: BatchOptions) -> BatchSummary:
    """Convert every capture into ``OUTDIR/NAME/`` and keep ``OUTDIR/batch.json`` up to date.

    Raises UserError for usage problems (before anything is converted). A failed capture never
    raises: it is recorded and the others go on. SIGTERM / SIGINT stop the running conversions
    (no partial output is left), record them as cancelled, and the summary's ``interrupted``
    names the signal.
    """
    from leaffit_usd.pipeline import ConvertOptions

    o = options
    _check_options(o)
    base = o.convert if o.convert is not None else ConvertOptions()
    outdir = Path(outdir).resolve()
    t0 = time.perf_counter()
    started = now_iso()
    summary = BatchSummary()

    with batch_lock(outdir):
        run = _Run(outdir=outdir, state=BatchState(outdir))
        _clean_leftovers(outdir)
        plan = _plan(captures, base, run.state, o.force)
        n_run = sum(1 for q in plan if not q.kept)
        if o.executor == "dask" and o.scheduler:
            jobs, threads = max(1, o.jobs or 1), o.threads or 1
        else:
            jobs, threads = plan_parallelism(n_run, o.jobs, o.threads)
        summary.jobs, summary.threads = jobs, threads
        _queue(run, plan, o, threads, started)
        run.run_info = {"started": started, "finished": None, "seconds": None,
                        "captures": len(captures), "converted": 0,
                        "skipped": sum(r["status"] == "skipped" for r in run.rows),
                        "not_retried": sum(r.get("retried") is False for r in run.rows),
                        "failed": 0, "exit_code": None, "executor": o.executor, "jobs": jobs,
                        "threads": threads}
        run.state.data["runs"].append(run.run_info)
        run.state.save()
        run.bar = _start_progress(run, o.progress, jobs, threads)
        old = _catch_interrupts()
        try:
            if run.tasks:
                _dispatch(run, o, jobs)
        except _Interrupted as e:
            summary.interrupted = signal.Signals(e.signum).name
            _cancel_unfinished(run, summary.interrupted)
        finally:
            for s, h in old.items():
                signal.signal(s, h)
            _finish(run, summary, t0)
    return summary


def _check_options(o: BatchOptions) -> None:
    """UserError (ParameterError) for a bad format, executor or timeout, or dask missing."""
    if o.stage_format not in STAGE_FORMATS:
        raise ParameterError("--format", " | ".join(STAGE_FORMATS), o.stage_format)
    if o.executor not in ("local", "dask"):
        raise ParameterError("--executor", "local or dask", o.executor)
    if o.timeout is not None and not o.timeout > 0:
        raise ParameterError("--timeout", "a positive number of seconds", o.timeout)
    if o.executor == "dask":
        from leaffit_usd.batch.executors import dask_available
        if not dask_available():
            from leaffit_usd.errors import UserError
            raise UserError("--executor dask needs dask.distributed: pip install 'leaffit-usd[dask]'")


def _plan(captures: list[Capture], base, state: BatchState, force: bool) -> list[_Planned]:
    """Each capture's options and hashes, and whether it is kept as it is."""
    from leaffit_usd.io_util import file_sha256

    plan = []
    for c in captures:
        copt = dataclasses.replace(base, **c.overrides) if c.overrides else base
        odict = options_json(copt)
        osha, isha = options_sha256(odict), file_sha256(c.path)
        plan.append(_Planned(c, copt, odict, osha, isha, _kept(state, c.name, isha, osha, force)))
    return plan


def _kept(state: BatchState, name: str, isha: str, osha: str, force: bool) -> str:
    """"done": complete and up to date; "failed": a bad-input failure (exit code 2) of
    this very input with these options, which would fail again; "" = convert."""
    if force:
        return ""
    if state.is_complete(name, isha, osha):
        return "done"
    rec = state.record(name)
    if rec.get("status") == "failed" and rec.get("exit_code") == 2 and \
            rec.get("input_sha256") == isha and rec.get("options_sha256") == osha:
        return "failed"
    return ""


def _queue(run: _Run, plan: list[_Planned], o: BatchOptions, threads: int, started: str) -> None:
    """A summary row per capture; kept captures are filled from the state, the others become
    tasks and are recorded as pending."""
    for q in plan:
        c = q.capture
        row = {"name": c.name, "input": str(c.path), "status": "", "leaves": None,
               "gaussians": None, "seconds": None, "error": "",
               "stage": f"{c.name}/{c.name}.{o.stage_format}"}
        run.rows.append(row)
        run.by_name[c.name] = row
        if c.renamed_from:
            log.warning("batch: %s is named %s (%s is taken)", c.path, c.name, c.renamed_from)
        if q.kept == "done":
            rec = run.state.record(c.name)
            row.update(status="skipped", leaves=rec.get("counts", {}).get("leaves"),
                       gaussians=rec.get("counts", {}).get("gaussians"),
                       seconds=rec.get("seconds"))
            continue
        if q.kept == "failed":
            row.update(status="failed", error=run.state.record(c.name).get("error", ""),
                       retried=False)
            continue
        run.tasks.append(CaptureTask(
            name=c.name, input=str(c.path), outdir=str(run.outdir),
            stage_name=f"{c.name}.{o.stage_format}", options=q.options, threads=threads,
            timeout=o.timeout, max_memory=o.max_memory))
        run.state.captures[c.name] = {
            "status": "pending", "input": str(c.path), "input_sha256": q.isha,
            "options_sha256": q.osha, "options": q.odict, "error": "", "exit_code": None,
            "seconds": None, "timings": {}, "counts": {}, "outputs": {},
            "stage": row["stage"], "log": f"{c.name}/{LOG_NAME}", "host": "",
            "threads": threads, "started": started, "finished": None,
            "renamed_from": c.renamed_from}


def _start_progress(run: _Run, progress: bool, jobs: int, threads: int):
    """The tqdm bar (None without progress or tasks) and the opening line on stderr."""
    bar = None
    if progress and run.tasks:
        from tqdm import tqdm

        bar = tqdm(total=len(run.tasks), unit="capture", file=sys.stderr, dynamic_ncols=True,
                   desc=f"batch ({jobs} job{'s' if jobs > 1 else ''} x {threads} thread"
                        f"{'s' if threads > 1 else ''})")
    if progress:
        sk = run.run_info["skipped"]
        nr = run.run_info["not_retried"]
        msg = (f"batch: {len(run.tasks)} to convert, {sk} up to date (skipped)"
               + (f", {nr} bad input(s) not retried" if nr else "") + f" -> {run.outdir}")
        with contextlib.suppress(OSError):
            (bar.write(msg, file=sys.stderr) if bar else sys.stderr.write(msg + "\n"))
    return bar


def _on_result(run: _Run, r: CaptureResult) -> None:
    """Record a finished capture in the state (saved at once) and its row; advance the bar."""
    rep = r.report or {}
    counts = rep.get("counts", {})
    run.state.update(r.name, status=r.status, error=r.error, exit_code=r.exit_code,
                     seconds=r.seconds, timings=rep.get("timings", {}), counts=counts,
                     outputs=r.outputs, host=r.host, finished=now_iso(),
                     fit={k: rep.get("fit", {}).get(k) for k in ("chamfer_mean", "chamfer_max")}
                     if rep.get("fit") else {})
    run.state.save()
    row = run.by_name[r.name]
    row.update(status=r.status, leaves=counts.get("leaves"), gaussians=counts.get("gaussians"),
               seconds=r.seconds, error=r.error)
    if run.bar is not None:
        with contextlib.suppress(OSError):   # a closed stderr must not stop the batch
            _progress(run, r, counts)


def _progress(run: _Run, r: CaptureResult, counts: dict) -> None:
    bar = run.bar
    bar.update(1)
    nf = sum(1 for x in run.rows if x["status"] in ("failed", "cancelled"))
    if nf:
        bar.set_postfix(failed=nf)
    line = (f"done    {r.name}: {counts.get('leaves')} leaves, {_fmt_s(r.seconds)} s"
            if r.status == "done" else f"{r.status:<7} {r.name}: {r.error}")
    bar.write(line, file=sys.stderr)


def _catch_interrupts() -> dict:
    """In the main thread, SIGTERM / SIGINT raise ``_Interrupted`` (once: the clean-up is not
    interrupted). Returns the previous handlers, by signal, for the caller to restore."""
    old = {}

    def handler(signum, frame):
        for s in old:                # one interruption: the clean-up is not interrupted
            signal.signal(s, signal.SIG_IGN)
        raise _Interrupted(signum)

    if hasattr(signal, "SIGTERM") and _in_main_thread():
        for s in (signal.SIGTERM, signal.SIGINT):
            old[s] = signal.signal(s, handler)
    return old


def _dispatch(run: _Run, o: BatchOptions, jobs: int) -> None:
    """Convert the tasks with the chosen executor; each result goes through ``_on_result``."""
    def on_result(r: CaptureResult) -> None:
        _on_result(run, r)

    if o.executor == "dask":
        from leaffit_usd.batch.executors import run_dask
        run_dask(run.tasks, jobs, on_result, o.scheduler)
    else:
        from leaffit_usd.batch.executors import run_local
        run_local(run.tasks, jobs, on_result)


def _cancel_unfinished(run: _Run, signame: str) -> None:
    """After an interruption: tasks without a result are cancelled (row and state)."""
    for t in run.tasks:
        row = run.by_name[t.name]
        if not row["status"]:
            row.update(status="cancelled", error=f"batch interrupted ({signame})")
        if run.state.record(t.name).get("status") == "pending":
            run.state.update(t.name, status="cancelled", error=row["error"], finished=now_iso())


def _finish(run: _Run, summary: BatchSummary, t0: float) -> None:
    """Remove work folders, fill the summary and this run's record, save the state, close the bar."""
    _clean_leftovers(run.outdir)
    rows = run.rows
    summary.rows = rows
    summary.seconds = round(time.perf_counter() - t0, 3)
    summary.exit_code = 0 if all(r["status"] in ("done", "skipped") for r in rows) else 1
    run.run_info.update(finished=now_iso(), seconds=summary.seconds,
                        converted=summary.count("done"),
                        failed=summary.count("failed") + summary.count("cancelled"),
                        exit_code=summary.exit_code if not summary.interrupted else None,
                        interrupted=summary.interrupted or None)
    run.state.save()
    if run.bar is not None:     # after the save: stderr may be a closed pipe by now
        with contextlib.suppress(Exception):
            run.bar.close()


def _in_main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def summary_table(summary: BatchSummary) -> str:
    """The end-of-batch table (plain text, one row per capture)."""
    head = ("capture", "status", "leaves", "Gaussians", "time s", "result")
    rows = []
    for r in summary.rows:
        rows.append((r["name"], r["status"] or "-",
                     "" if r["leaves"] is None else str(r["leaves"]),
                     "" if r["gaussians"] is None else f"{r['gaussians']:,}",
                     "" if r["seconds"] is None else _fmt_s(r["seconds"]),
                     r["stage"] if r["status"] in ("done", "skipped") else r["error"]))
    w = [max(len(h), *(len(x[i]) for x in rows)) if rows else len(h) for i, h in enumerate(head)]
    def fmt(cells):
        return "  ".join(c.rjust(w[i]) if i in (2, 3, 4) else c.ljust(w[i])
                         for i, c in enumerate(cells)).rstrip()
    lines = [fmt(head), fmt(tuple("-" * x for x in w))] + [fmt(x) for x in rows]
    n = len(summary.rows)
    nr = sum(r.get("retried") is False for r in summary.rows)
    lines.append(f"{n} capture{'s' if n != 1 else ''}: {summary.count('done')} converted, "
                 f"{summary.count('skipped')} skipped (up to date), {summary.count('failed')} failed"
                 + (f" ({nr} not retried: same input and options, --force retries)" if nr else "")
                 + (f", {summary.count('cancelled')} cancelled" if summary.count("cancelled") else "")
                 + f" in {summary.seconds:.1f} s ({summary.jobs} job{'s' if summary.jobs > 1 else ''}"
                 f" x {summary.threads} thread{'s' if summary.threads > 1 else ''})")
    return "\n".join(lines)
