"""What a benchmark result was measured on: the machine, the libraries, the commit.

The conversion is byte-identical run to run on one machine (``tests/test_determinism.py``), but
not across machines: torch and OpenBLAS choose their kernels by the CPU's vector instructions
(AVX-512, AVX2, ...), and a fresh install may take other numpy / scipy releases within
pyproject's ranges. Either changes the last bits of the registration's sums, and its 200 Adam
steps carry that into the third digit of a fit error or a render IoU (``benchmarks/render.py``:
overlap's worst-view IoU 0.895 on one machine, 0.899 on an AMD EPYC with AVX2, the same code, both
runs repeatable to the byte on their own machine). Every results JSON therefore records this block,
so two tables can be told apart by their code or by their machine.
"""
from __future__ import annotations

import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path

# distributions whose numerics reach the results (the segmentation, fit, mesh and render stages)
PACKAGES = ("numpy", "scipy", "torch", "open3d", "potpourri3d", "trimesh", "triangle", "usd-core")
# vector-instruction flags of /proc/cpuinfo that select different kernels in torch / OpenBLAS
ISA_FLAGS = ("avx512f", "avx2", "fma", "avx")


def cpu_model_and_flags(cpuinfo: str) -> tuple[str, list[str]]:
    """(model name, the ISA_FLAGS present) from the text of /proc/cpuinfo ('' and [] when absent)."""
    model, flags = "", set()
    for line in cpuinfo.splitlines():
        key, _, value = line.partition(":")
        key = key.strip()
        if key == "model name" and not model:
            model = value.strip()
        elif key in ("flags", "Features") and not flags:
            flags = set(value.split())
    return model, [f for f in ISA_FLAGS if f in flags]


def _git(root: Path, *args: str) -> str | None:
    try:
        out = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True,
                             timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def _commit(root: Path) -> str | None:
    """Short hash of HEAD, with '+dirty' when tracked files differ from it (None: no git)."""
    head = _git(root, "rev-parse", "--short", "HEAD")
    if not head:
        return None
    return head + ("+dirty" if _git(root, "status", "--porcelain", "--untracked-files=no") else "")


def machine_info() -> dict:
    """JSON-ready: cpu model, ISA flags, cores available, load average (1 min), Python and the
    PACKAGES' installed versions (None: not installed), the repository's commit ('+dirty' with
    uncommitted changes to tracked files; None outside a git checkout)."""
    try:
        model, isa = cpu_model_and_flags(Path("/proc/cpuinfo").read_text())
    except OSError:
        model, isa = platform.processor(), []
    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return {"cpu": model, "isa": isa, "cores": len(os.sched_getaffinity(0)),
            "load_average": round(os.getloadavg()[0], 2), "python": platform.python_version(),
            "packages": versions, "commit": _commit(Path(__file__).resolve().parents[1])}
