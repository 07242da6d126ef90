"""The one task function of a batch: convert one capture in its own process.

:func:`run_capture` is what the local executor runs in a thread and what a Dask worker runs: it
starts ``python -m leaffit_usd.batch.worker`` (a fresh interpreter: a crash, a leak or a hung
native library takes only that capture down) with the capture's log as its stdout/stderr, and
watches it for the time limit, the memory limit and cancellation.

Files, for a capture named ``NAME`` in ``OUTDIR``::

    OUTDIR/NAME/convert.log            the worker's log (written while it runs)
    OUTDIR/NAME/.work-<id>/            the worker's output folder while it runs
    OUTDIR/NAME/NAME.usda              } moved out of .work-<id> only when the conversion
    OUTDIR/NAME/textures/, *.baked.*   } succeeded, the stage last; a failed, timed-out or
    OUTDIR/NAME/report.json            } cancelled capture leaves only convert.log

A rerun removes a capture's old outputs before converting it again, so what is in ``OUTDIR/NAME``
is always the result of one conversion. Everything here runs on the machine that converts (a Dask
worker): paths must be valid there (a shared filesystem).
"""
from __future__ import annotations

import contextlib
import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
import time
import uuid
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

WORK_PREFIX = ".work-"
LOG_NAME = "convert.log"
REPORT_NAME = "report.json"
RESULT_NAME = ".result.json"     # worker -> task: status and error line (inside the work folder)


@dataclass
class CaptureTask:
    """Everything a worker needs to convert one capture (picklable, paths absolute).

    name : output folder name; input : capture file; outdir : the batch's output folder
    stage_name : the stage's file name (``NAME.usda``); options : ``pipeline.ConvertOptions``
    threads : torch / BLAS threads of the worker process
    timeout : seconds before the worker is killed (None = no limit)
    max_memory : bytes of resident memory before the worker is killed (None = no limit)
    """

    name: str
    input: str
    outdir: str
    stage_name: str
    options: object
    threads: int = 1
    timeout: float | None = None
    max_memory: int | None = None

    @property
    def capture_dir(self) -> Path:
        return Path(self.outdir) / self.name


@dataclass
class CaptureResult:
    """What became of one task.

    status : "done" | "failed" | "cancelled"; error : one line ("" when done)
    exit_code : the worker's (negative = killed by that signal; None = never started)
    seconds : wall time of the worker; outputs : {path relative to OUTDIR/NAME: bytes}
    report : the conversion report (``pipeline.convert``) when done, else {}
    host : the machine that ran it
    """

    name: str
    status: str
    error: str = ""
    exit_code: int | None = None
    seconds: float = 0.0
    outputs: dict = field(default_factory=dict)
    report: dict = field(default_factory=dict)
    host: str = ""

    def to_dict(self) -> dict:
        return asdict(self)


def thread_env(threads: int, base: dict | None = None) -> dict:
    """Environment for a process limited to ``threads`` compute threads (OpenMP, BLAS, torch)."""
    env = dict(os.environ if base is None else base)
    t = str(max(1, int(threads)))
    for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
              "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS"):
        env[k] = t
    return env


def _rss_bytes(pid: int) -> int:
    """Resident memory of a process (Linux /proc; 0 where unavailable)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return 0


def _kill(proc: subprocess.Popen, grace: float = 5.0) -> None:
    """SIGTERM the worker's process group, SIGKILL after ``grace`` seconds."""
    for sig, wait in ((signal.SIGTERM, grace), (signal.SIGKILL, 30.0)):
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(proc.pid, sig)
        try:
            proc.wait(wait)
            return
        except subprocess.TimeoutExpired:
            continue


def clear_outputs(capture_dir: Path) -> None:
    """Remove a capture folder's previous outputs (everything in it)."""
    if capture_dir.is_dir():
        for p in capture_dir.iterdir():
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                with contextlib.suppress(FileNotFoundError):
                    p.unlink()


def list_outputs(capture_dir: Path) -> dict:
    """{relative path: size in bytes} of the files of a finished capture (log and work folders
    excluded), sorted."""
    out = {}
    for p in sorted(capture_dir.rglob("*")):
        rel = p.relative_to(capture_dir)
        if p.is_file() and rel.as_posix() != LOG_NAME and not rel.parts[0].startswith(WORK_PREFIX):
            out[rel.as_posix()] = p.stat().st_size
    return out


def run_capture(task: CaptureTask, should_stop: Callable[[], bool] | None = None,
                poll: float = 0.25) -> CaptureResult:
    """Convert one capture in a worker process; never raises for a failed conversion.

    should_stop : polled while the worker runs; True cancels it (status "cancelled").
    """
    import socket

    host = socket.gethostname()
    cdir = task.capture_dir
    cdir.mkdir(parents=True, exist_ok=True)
    clear_outputs(cdir)
    work = cdir / f"{WORK_PREFIX}{uuid.uuid4().hex[:12]}"
    work.mkdir()
    log_path = cdir / LOG_NAME
    payload = pickle.dumps({"task": task, "work": str(work), "parent": os.getpid()})
    t0 = time.perf_counter()
    status, error, code = "failed", "", None
    try:
        with open(log_path, "w", encoding="utf-8") as log:
            log.write(f"# leaffit-usd batch: {task.name} <- {task.input} on {host}, "
                      f"{task.threads} thread(s), started {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
            log.flush()
            proc = subprocess.Popen(
                [sys.executable, "-m", "leaffit_usd.batch.worker"], stdin=subprocess.PIPE,
                stdout=log, stderr=subprocess.STDOUT, cwd=str(work), env=thread_env(task.threads),
                start_new_session=True)
            try:
                proc.stdin.write(payload)
                proc.stdin.close()
            except BrokenPipeError:
                pass
            why = ""
            peak = 0
            while True:
                try:
                    code = proc.wait(poll)
                    break
                except subprocess.TimeoutExpired:
                    pass
                elapsed = time.perf_counter() - t0
                if task.timeout is not None and elapsed > task.timeout:
                    why = f"timed out after {task.timeout:g} s (--timeout)"
                elif task.max_memory is not None:
                    peak = max(peak, _rss_bytes(proc.pid))
                    if peak > task.max_memory:
                        why = (f"used more than {task.max_memory / 2**30:.3g} GiB of memory "
                               "(--max-memory)")
                if not why and should_stop is not None and should_stop():
                    why = "cancelled"
                if why:
                    _kill(proc)
                    code = proc.returncode
                    break
            seconds = time.perf_counter() - t0
            result = {}
            with contextlib.suppress(OSError, ValueError):
                result = json.loads((work / RESULT_NAME).read_text())
            stage = work / task.stage_name
            if why:
                status, error = ("cancelled" if why == "cancelled" else "failed"), why
            elif code == 0 and result.get("status") == "done" and stage.is_file():
                status = "done"
            elif result.get("error"):
                error = result["error"]
            elif code is not None and code < 0:
                sig = signal.Signals(-code).name if -code in signal.Signals._value2member_map_ else -code
                error = f"worker killed by {sig}" + (" (out of memory?)" if code == -signal.SIGKILL else "")
            else:
                error = f"worker exited with code {code} and no result (see {LOG_NAME})"
            log.write(f"# {status}{': ' + error if error else ''} after {seconds:.1f} s "
                      f"(exit code {code})\n")
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    outputs, report = {}, {}
    if status == "done":
        report = result.get("report", {})
        # the stage last: its presence means every file it refers to is in place
        for p in sorted(work.iterdir(), key=lambda p: (p.name == task.stage_name, p.name)):
            if p.name != RESULT_NAME:
                os.replace(p, cdir / p.name)
        outputs = list_outputs(cdir)
    shutil.rmtree(work, ignore_errors=True)
    return CaptureResult(task.name, status, error, code, round(seconds, 3), outputs, report, host)
