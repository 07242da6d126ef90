"""The external plant sets of ``../shared/plants`` (generators nobody on the team wrote), for the
benchmarks: where they are, generating them once into a cache folder, and their ground truth.

``../shared/plants`` is optional: :func:`shared_plants_dir` returns None when it is absent and the
benchmarks print a message and skip those sets. Nothing in ``tests/`` or ``make test`` uses this.

Sets (name -> generator, preset): ``paper8`` and ``hard4`` (make_plants.py), ``heliosdev8``
(helios_plants.py, run in the Helios venv that ``helios_venv.sh`` makes), ``scene`` (paper8 with
``--scene``: pot, soil, table, clutter). Plants are cached in ``$LEAFFIT_EXT_CACHE`` (default
``~/.cache/leaffit-plants/sets``) as ``<set>-<seed>/<plant>/{point_cloud.ply,gt.npz}``.
"""
from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SETS = {
    "paper8": ("make_plants.py", ["--preset", "paper8"]),
    "hard4": ("make_plants.py", ["--preset", "hard4"]),
    "heliosdev8": ("helios_plants.py", []),
    "scene": ("make_plants.py", ["--preset", "paper8", "--scene"]),
}


def shared_plants_dir() -> Path | None:
    """``../shared/plants`` beside the repo (or ``$LEAFFIT_SHARED_PLANTS``), None if absent."""
    env = os.environ.get("LEAFFIT_SHARED_PLANTS")
    d = Path(env) if env else ROOT.parent / "shared" / "plants"
    return d if (d / "eval_seg.py").exists() else None


def cache_dir() -> Path:
    base = os.environ.get("LEAFFIT_EXT_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "leaffit-plants", "sets")
    return Path(base)


def _python_for(script: str, shared: Path) -> str:
    """The generators need numpy, scipy, pillow and plyfile (and pyhelios3d for Helios): the venv
    that ``helios_venv.sh`` makes has them all (ours has no pillow)."""
    out = subprocess.run(["bash", str(shared / "helios_venv.sh")], check=True, capture_output=True,
                         text=True)
    return out.stdout.strip().splitlines()[-1]


def ensure_set(name: str, seed: int, gaussians: int | None = None, count: int | None = None) -> Path:
    """Folder of set ``name`` at ``seed`` (generated on first use; 1-15 s a plant); ``gaussians``
    and ``count`` pass ``--gaussians`` / ``--count`` to the generator (scale tests)."""
    shared = shared_plants_dir()
    if shared is None:
        raise FileNotFoundError("../shared/plants is absent")
    script, extra = SETS[name]
    tag = f"{name}-{seed}" + (f"-n{gaussians}" if gaussians else "") + (f"-c{count}" if count else "")
    out = cache_dir() / tag
    if (out / "index.json").exists():
        return out
    if script == "make_plants.py":
        subprocess.run(["bash", str(shared / "fetch_assets.sh")], check=True, capture_output=True)
    cmd = [_python_for(script, shared), str(shared / script), "--out", str(out), "--seed", str(seed),
           "--quiet", *extra]
    if gaussians:
        cmd += ["--gaussians", str(gaussians)]
    if count:
        cmd += ["--count", str(count)]
    subprocess.run(cmd, check=True)
    return out


def plants(folder: Path) -> list[Path]:
    """Plant folders (holding ``gt.npz``) of a generated set, sorted by name."""
    return sorted(p.parent for p in Path(folder).glob("*/gt.npz"))


def load_module(name: str):
    """Import one of the shared scripts (``eval_seg``, ``eval_deform``) as a module."""
    shared = shared_plants_dir()
    if shared is None:
        raise FileNotFoundError("../shared/plants is absent")
    if str(shared) not in sys.path:
        sys.path.insert(0, str(shared))
    spec = importlib.util.spec_from_file_location(f"shared_{name}", shared / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
