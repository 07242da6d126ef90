"""Worker process of a batch: ``python -m leaffit_usd.batch.worker`` < pickled task.

Started by :func:`leaffit_usd.batch.task.run_capture` with the capture's log as stdout/stderr and
its work folder as the current directory. Converts one capture with ``pipeline.convert`` into
the work folder and writes ``.result.json`` there (status, one-line error, the report). Exit
codes as the CLI: 0 done, 2 bad input (UserError), 1 internal error (the traceback goes to the
log). On Linux it asks to be killed when its parent dies, so a killed batch leaves no orphan
that would move outputs into place behind a rerun.
"""
from __future__ import annotations

import json
import logging
import os
import pickle
import signal
import sys
import traceback
from pathlib import Path


def _die_with_parent(parent: int) -> None:
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL("libc.so.6", use_errno=True)
            libc.prctl(1, signal.SIGKILL)          # PR_SET_PDEATHSIG
        except OSError:
            pass
    if os.getppid() != parent:                     # the parent died before prctl
        os._exit(3)


def _relative_report(report: dict, work: Path) -> dict:
    """The report with paths inside the work folder made relative (they are moved after)."""
    def rel(v):
        try:
            return Path(v).relative_to(work).as_posix()
        except ValueError:
            return v
    out = dict(report)
    out["output"] = rel(report.get("output", ""))
    out["outputs"] = {k: rel(v) for k, v in report.get("outputs", {}).items()}
    return out


def main() -> int:
    msg = pickle.loads(sys.stdin.buffer.read())      # from run_capture, our own parent
    _die_with_parent(int(msg["parent"]))
    # SIGTERM from the batch (cancel, time limit) -> a clean exit through the finally clauses
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    task, work = msg["task"], Path(msg["work"])
    threads = max(1, int(task.threads))

    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(asctime)s %(message)s", "%H:%M:%S"))
    log = logging.getLogger("leaffit_usd")
    log.handlers[:] = [handler]
    log.setLevel(logging.INFO)
    log.propagate = False

    def result(**kw):
        (work / ".result.json").write_text(json.dumps(kw, indent=1) + "\n")

    try:
        import torch

        torch.set_num_threads(threads)
        from leaffit_usd.errors import UserError
        from leaffit_usd.pipeline import convert
    except Exception as e:  # noqa: BLE001
        traceback.print_exc()
        result(status="failed", error=f"internal error: {type(e).__name__}: {e}")
        return 1
    try:
        report = convert(task.input, work / task.stage_name, task.options)
    except UserError as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        sys.stderr.write(f"error: {msg}\n")
        result(status="failed", error=msg)
        return 2
    except MemoryError:
        traceback.print_exc()
        result(status="failed", error="out of memory")
        return 1
    except Exception as e:  # noqa: BLE001 - an internal error of this capture only
        traceback.print_exc()
        msg = f"internal error: {type(e).__name__}: {e}".splitlines()[0]
        result(status="failed", error=msg)
        return 1
    report = _relative_report(report, work)
    report["threads"] = threads
    (work / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    result(status="done", report=report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
