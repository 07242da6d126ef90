"""Where a conversion spends its time: each stage's wall time and its hot spots (cProfile).

Plants (each converted once in this process, default options, ``.usdz`` output):

* ``100k`` — the generated green pepper at 100,000 Gaussians (``samples``, 9 leaves), or
  ``--plant PLY`` (e.g. a paper8 plant from ``~/.cache/leaffit-plants/sets/paper8-1``);
* ``houseplant`` — the real capture ``../shared/real/houseplant.splat`` (``--up -y``); skipped with
  a message when the file is absent;
* ``1m`` — the same green pepper at 1,000,000 Gaussians (``--skip-1m`` leaves it out).

Per plant: a table of the stages (``convert``'s report timings, seconds) beside the last run's
figures (``benchmarks/results/profile_convert.json``, read before it is overwritten), then the
top ``--top`` functions of each slow stage by own time (tottime) and by cumulative time, from a
cProfile of that stage's function alone (``fit_leaves``, ``build_template_mesh``,
``build_stem``, ``measure_leaf_tints``, ``write_stage``; segmentation and isolation as a whole
with ``--all-stages``). The peak RSS is the process's (``ru_maxrss``) after each plant, so the
1M row shows the largest one when it runs last.

cProfile slows Python-heavy code by up to ~2x, so the stage times printed come from a second,
unprofiled conversion when ``--timed`` is given (median of ``--timed`` runs); by default the
one profiled run's times are shown (their ratios are what the table is for).

    .venv/bin/python benchmarks/profile_convert.py [--plant PLY] [--skip-1m] [--top 12]
        [--timed 3] [--only 100k,houseplant]
"""
from __future__ import annotations

import argparse
import cProfile
import io
import json
import pstats
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

RESULTS = ROOT / "benchmarks" / "results" / "profile_convert.json"
HOUSEPLANT = ROOT.parent / "shared" / "real" / "houseplant.splat"
STAGES = ("load", "isolate", "frame", "segment", "fit", "mesh", "stem", "tint", "write")
# the stage functions profiled one by one: (module, attribute, stage name)
HOOKS = (("leaffit_usd.fit.register", "fit_leaves", "fit"),
         ("leaffit_usd.mesh.template", "build_template_mesh", "mesh"),
         ("leaffit_usd.mesh.stem", "build_stem", "stem"),
         ("leaffit_usd.mesh.appearance", "measure_leaf_tints", "tint"),
         ("leaffit_usd.usd.writer", "write_stage", "write"))


def _generated(gaussians: int, work: Path) -> Path:
    """The green pepper preset at ``gaussians`` Gaussians (cached in ``work``)."""
    from samples.generate import main as generate

    name = f"green_pepper_{gaussians}"
    ply = work / f"{name}.ply"
    if not ply.is_file():
        generate(["--preset", "green_pepper", "--gaussians", str(gaussians), "--out", str(work),
                  "--name", name, "-q"])
    return ply


class _StageProfiles:
    """cProfile of each hooked stage function, installed on its module for one conversion."""

    def __init__(self):
        self.profiles: dict[str, cProfile.Profile] = {}
        self._saved = []

    def __enter__(self):
        import importlib

        for mod_name, attr, stage in HOOKS:
            mod = importlib.import_module(mod_name)
            fn = getattr(mod, attr)
            self._saved.append((mod, attr, fn))
            setattr(mod, attr, self._wrap(fn, stage))
        return self

    def _wrap(self, fn, stage):
        def run(*a, **kw):
            prof = self.profiles.setdefault(stage, cProfile.Profile())
            return prof.runcall(fn, *a, **kw)
        return run

    def __exit__(self, *exc):
        for mod, attr, fn in self._saved:
            setattr(mod, attr, fn)
        return False


def _convert(src: Path, out: Path, up):
    from leaffit_usd.pipeline import ConvertOptions, convert

    opts = ConvertOptions(up=up)
    return convert(src, out, opts)


def _hot_spots(prof: cProfile.Profile, top: int) -> list[dict]:
    """The ``top`` functions by own time: name, own and cumulative seconds, calls."""
    st = pstats.Stats(prof, stream=io.StringIO())
    rows = []
    for (file, line, fn), (cc, nc, tt, ct, _) in st.stats.items():
        short = file.split("site-packages/")[-1].replace(str(ROOT) + "/", "")
        rows.append({"function": f"{short}:{line}({fn})", "tottime": round(tt, 3),
                     "cumtime": round(ct, 3), "calls": nc})
    rows.sort(key=lambda r: -r["tottime"])
    return rows[:top]


def profile_plant(name: str, src: Path, up, top: int, timed: int, work: Path) -> dict:
    """Convert ``src`` once under the stage profiles (and ``timed`` more times unprofiled)."""
    t0 = time.perf_counter()
    with _StageProfiles() as sp:
        rep = _convert(src, work / name / f"{name}.usdz", up)
    wall = time.perf_counter() - t0
    timings = dict(rep["timings"])
    runs = []
    for _ in range(timed):
        runs.append(_convert(src, work / name / f"{name}.usdz", up)["timings"])
    if runs:
        timings = {k: round(statistics.median(r.get(k, 0.0) for r in runs), 3) for k in runs[0]}
    return {
        "plant": name, "input": str(src), "gaussians": rep["counts"]["gaussians"],
        "leaves": rep["counts"]["leaves"], "timings": timings, "profiled_wall_s": round(wall, 2),
        "timed_runs": timed, "usdz_bytes": rep["sizes"]["output_bytes"],
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "hot_spots": {stage: _hot_spots(p, top) for stage, p in sp.profiles.items()},
    }


def _print_plant(row: dict, before: dict | None) -> None:
    print(f"\n== {row['plant']}: {row['gaussians']:,} Gaussians, {row['leaves']} leaves, "
          f"usdz {row['usdz_bytes'] / 1e6:.2f} MB, peak RSS {row['peak_rss_mb']:.0f} MB "
          f"({'median of %d unprofiled runs' % row['timed_runs'] if row['timed_runs'] else 'profiled run'})")
    bt = (before or {}).get("timings", {})
    print(f"{'stage':10s} {'now s':>8s} {'last s':>8s}")
    for k in list(STAGES) + ["total"]:
        if k in row["timings"]:
            last = f"{bt[k]:8.2f}" if k in bt else f"{'-':>8s}"
            print(f"{k:10s} {row['timings'][k]:8.2f} {last}")
    for stage, spots in row["hot_spots"].items():
        if row["timings"].get(stage, 0.0) < 0.2:
            continue
        print(f"-- {stage}: top functions by own time (s)")
        for s in spots:
            print(f"   {s['tottime']:7.3f} own {s['cumtime']:7.3f} cum {s['calls']:>8d}x  {s['function']}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plant", default=None, help="a 100k-class PLY instead of the generated pepper")
    ap.add_argument("--only", default="100k,houseplant,1m", help="which plants (comma list)")
    ap.add_argument("--skip-1m", action="store_true")
    ap.add_argument("--top", type=int, default=12)
    ap.add_argument("--timed", type=int, default=0, help="unprofiled runs for the stage times")
    ap.add_argument("--work", default=None, help="where inputs and outputs go (default: a temp dir)")
    ap.add_argument("--out", default=str(RESULTS))
    args = ap.parse_args(argv)
    import logging

    logging.getLogger("leaffit_usd").setLevel(logging.WARNING)
    work = Path(args.work or tempfile.mkdtemp(prefix="leaffit_profile_"))
    work.mkdir(parents=True, exist_ok=True)
    last = {}
    if Path(args.out).is_file():
        last = {r["plant"]: r for r in json.loads(Path(args.out).read_text()).get("plants", [])}
    wanted = [w.strip() for w in args.only.split(",") if w.strip()]
    if args.skip_1m and "1m" in wanted:
        wanted.remove("1m")
    rows = []
    for name in wanted:
        up = None
        if name == "100k":
            src = Path(args.plant) if args.plant else _generated(100_000, work)
        elif name == "houseplant":
            if not HOUSEPLANT.is_file():
                print(f"\n== houseplant: skipped ({HOUSEPLANT} is absent)")
                continue
            src, up = HOUSEPLANT, (0.0, -1.0, 0.0)
        elif name == "1m":
            src = _generated(1_000_000, work)
        else:
            print(f"unknown plant {name!r} (100k, houseplant, 1m)", file=sys.stderr)
            return 2
        import numpy as np

        row = profile_plant(name, src, None if up is None else np.array(up), args.top, args.timed, work)
        _print_plant(row, last.get(name))
        rows.append(row)
    from leaffit_usd.io_util import atomic_write_bytes

    merged = {**last, **{r["plant"]: r for r in rows}}
    atomic_write_bytes(Path(args.out), json.dumps({"plants": list(merged.values())}, indent=1).encode())
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
