"""``OUTDIR/batch.json``: the state of a batch, rewritten atomically after every change.

Layout (format 1)::

    {"tool": "leaffit-usd", "version": ..., "format": 1,
     "captures": {NAME: {                     one record per capture ever converted into OUTDIR
         "status": "done" | "failed" | "pending" (queued or running) | "cancelled",
         "input": path, "input_sha256": hex, "options_sha256": hex, "options": {...},
         "error": one line ("" when done), "exit_code": int | null,
         "seconds": worker wall time, "timings": {stage: s}, "counts": {...},
         "outputs": {path relative to OUTDIR/NAME: bytes}, "stage": "NAME/NAME.usda",
         "log": "NAME/convert.log", "host": ..., "threads": int, "fit": {chamfer_mean, max},
         "started": ISO time, "finished": ISO time, "renamed_from": "" | name}},
     "runs": [{"started", "finished", "seconds", "captures", "converted", "skipped",
               "not_retried", "failed", "exit_code", "interrupted", "executor", "jobs",
               "threads"}]}

A record is "done" only when its outputs were moved into place; a killed batch leaves "pending"
or "cancelled" records, which a rerun converts again (as it does "failed" ones, except a bad
input, exit code 2, whose input and options are unchanged). Only the process that runs the
batch writes this file (executors report results to it): one writer, atomic replaces.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import time
from pathlib import Path

from leaffit_usd.version import __version__
from leaffit_usd.errors import InputFileError
from leaffit_usd.io_util import atomic_write_bytes

STATE_NAME = "batch.json"
LOCK_NAME = ".batch.lock"
FORMAT = 1


def now_iso() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def options_json(options) -> dict:
    """A ``ConvertOptions`` (nested parameter dataclasses, numpy vectors) as plain JSON values."""
    import dataclasses

    import numpy as np

    def default(o):
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, np.generic):
            return o.item()
        return str(o)

    return json.loads(json.dumps(dataclasses.asdict(options), default=default, sort_keys=True))


def options_sha256(options: dict) -> str:
    """Hash of a capture's conversion options (ConvertOptions as a dict, the tool version and the
    contents of the files they name): a change to any of them redoes the capture."""
    from leaffit_usd.io_util import file_sha256

    files = {k: file_sha256(options[k]) for k in ("labels", "edits")
             if options.get(k) and Path(options[k]).is_file()}
    blob = json.dumps({"options": options, "files": files, "version": __version__},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()


class BatchState:
    """The records of ``OUTDIR/batch.json``; :meth:`save` rewrites the file atomically."""

    def __init__(self, outdir: Path):
        self.outdir = Path(outdir)
        self.path = self.outdir / STATE_NAME
        self.data = {"tool": "leaffit-usd", "version": __version__, "format": FORMAT,
                     "captures": {}, "runs": []}
        if self.path.exists():
            try:
                data = json.loads(self.path.read_text(encoding="utf-8"))
                if not isinstance(data, dict) or not isinstance(data.get("captures"), dict):
                    raise ValueError("no 'captures' object")
            except (OSError, ValueError) as e:
                raise InputFileError(self.path, f"not a batch state file ({e}); move it away "
                                                "or choose another output folder") from None
            self.data.update(data)
            self.data["version"] = __version__
            self.data.setdefault("runs", [])

    @property
    def captures(self) -> dict:
        return self.data["captures"]

    def record(self, name: str) -> dict:
        return self.captures.get(name, {})

    def update(self, name: str, **fields) -> dict:
        rec = self.captures.setdefault(name, {})
        rec.update(fields)
        return rec

    def save(self) -> None:
        self.outdir.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(self.path, (json.dumps(self.data, indent=1, sort_keys=False) + "\n").encode())

    def is_complete(self, name: str, input_sha: str, options_sha: str) -> bool:
        """True when ``name`` was converted from this input with these options and every output
        file it listed is still there with its size."""
        rec = self.record(name)
        if rec.get("status") != "done" or rec.get("input_sha256") != input_sha \
                or rec.get("options_sha256") != options_sha or not rec.get("outputs"):
            return False
        cdir = self.outdir / name
        for rel, size in rec["outputs"].items():
            p = cdir / rel
            with contextlib.suppress(OSError):
                if p.is_file() and p.stat().st_size == size:
                    continue
            return False
        return True


@contextlib.contextmanager
def batch_lock(outdir: Path):
    """An exclusive lock on OUTDIR (``OUTDIR/.batch.lock``): two batches never write one folder."""
    import fcntl

    from leaffit_usd.errors import UserError

    outdir.mkdir(parents=True, exist_ok=True)
    path = outdir / LOCK_NAME
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    locked = False
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UserError(f"{outdir}: another leaffit-usd batch is writing to this folder") from None
        locked = True
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield
    finally:
        if locked:   # removed while held: a batch waiting for it fails at once (LOCK_NB)
            with contextlib.suppress(OSError):
                path.unlink()
        os.close(fd)
