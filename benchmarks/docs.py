"""Generate ``docs/benchmarks/*.md`` from ``benchmarks/results/*.json``: one page per results
file, with the command that produced it, the machine block when the file has one, and its tables
rendered from the JSON; plus ``docs/benchmarks/index.md``.

    .venv/bin/python -m benchmarks.docs            # rewrite docs/benchmarks/
    .venv/bin/python -m benchmarks.docs --check    # exit 1 when docs/benchmarks/ is not current

Run it after a benchmark writes or updates a results JSON (``tests/benchmarks/test_docs.py``
fails until you do). A new results file needs a row in ``RESULTS`` below: its benchmark, the
command, and one line on what it measured. The pages carry no timestamp, so the same JSON files
give the same bytes.

Rendering is generic: a dict of scalars is a two-column table, a list of dicts is a table (nested
dicts flattened into dotted columns, split into tables of at most ``MAX_COLUMNS`` value columns),
a dict of such dicts is a table keyed by its keys, anything else nested is a subsection. Floats
keep 4 significant digits. A per-row value that is itself a long list (per-leaf, per-view arrays)
is left out of the table and named under it: the JSON has it.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS_DIR = ROOT / "benchmarks" / "results"
DOCS_DIR = ROOT / "docs" / "benchmarks"
MAX_COLUMNS = 12          # value columns per table (identifying columns are repeated)
MAX_INLINE_LIST = 8       # a list of scalars up to this long is shown in its cell
MAX_STRING = 240          # longer strings (encoded arrays) are shown by their length
PY = ".venv/bin/python"
EXT = "LEAFFIT_EXT_CACHE=/work/ext "


@dataclass(frozen=True)
class Result:
    """One results file: which benchmark wrote it, how, and what it holds."""
    path: str          # relative to benchmarks/results
    benchmark: str     # the script's name in benchmarks/
    command: str       # the command line(s) that produced the file
    what: str          # one line: what was measured, and on which code when it is not current
    topic: str = ""    # the docs/ page that explains the method and reads the figures


# The current result of each benchmark comes first in its group; later rows are earlier runs kept
# because a docs page compares against them.
RESULTS: tuple[Result, ...] = (
    Result("isolation.json", "isolation",
           f"{EXT}{PY} benchmarks/isolation.py --set all --ext-seeds 1 2 3 --cache /work/ext/iso-samples-cache",
           "Capture (pot, soil, table, clutter) against the trimmed plant through convert's front half: "
           "up and root error, mIoU both ways and attributed, scene kept, plant lost; 6 samples and "
           "paper8 seeds 1-3.", "isolation.md"),
    Result("isolation_seed1_a7fda81.json", "isolation",
           f"{PY} benchmarks/isolation.py --set all --ext-seeds 1 --out benchmarks/results/isolation_seed1_a7fda81.json",
           "The same on the samples and paper8 seed 1 after the face-contact rule (a7fda81).", "isolation.md"),
    Result("isolation_convert.json", "isolation",
           f"{EXT}{PY} benchmarks/isolation.py --set all --ext-seeds 1 --convert --cache /work/ext/iso-samples-cache "
           "--out benchmarks/results/isolation_convert.json",
           "The whole convert of each capture, baked: each asset vertex's distance from the nearest true "
           "plant Gaussian (asset geometry outside the plant).", "isolation.md"),
    Result("isolation_keep.json", "isolation_keep",
           f"{PY} benchmarks/isolation_keep.py --seeds 1 2 3",
           "The share of each plant that isolation keeps, on every generated and shared plant.", "isolation.md"),
    Result("real.json", "real", f"{PY} benchmarks/real.py",
           "The real houseplant capture converted with no options: up error, cue, leaves against a "
           "hand-audited count, asset vertices below the soil, removed classes.", "isolation.md"),
    Result("editor.json", "editor", f"{PY} -m benchmarks.editor",
           "The segmentation editor: edit -> fitted-leaf preview latency on a 100k plant, and a 1M "
           "capture's open time (URL, first frame of splats, tools ready).", "editor.md"),
    Result("pot.json", "pot", f"{PY} benchmarks/pot.py",
           "convert --pot: the pot mesh's two-sided Chamfer distance to the pot's Gaussians over the "
           "plant height (capture-like samples, the --scene plants, the real houseplant).", "isolation.md"),
    Result("capture_stats.json", "capture_stats", f"{PY} benchmarks/capture_stats.py",
           "Per-Gaussian statistics of the real houseplant capture beside the generator's capture-realism "
           "and ideal plants.", "isolation.md"),
    Result("up_axis.json", "up_axis",
           f"{PY} benchmarks/up_axis.py; LEAFFIT_SHARED_PLANTS=../shared/plants {PY} benchmarks/up_axis.py --set external",
           "Up-axis and automatic-root error on randomly rotated plants (samples, and the external sets).",
           "isolation.md"),
    Result("segmentation.json", "segmentation", f"{PY} benchmarks/segmentation.py --external",
           "The paper's Table 1 on our 14-preset suite (Acc, mIoU, mF1, PQ, time), ours against the "
           "baselines.", "segmentation.md"),
    Result("segmentation_external/external_seeds123.json", "seg_external",
           f"{PY} benchmarks/seg_external.py --out benchmarks/results/segmentation_external/external_seeds123.json; "
           f"{PY} benchmarks/seg_tables.py benchmarks/results/segmentation_external/external_seeds123.json",
           "Segmentation on the external sets paper8, hard4, heliosdev8, seeds 1-3: root given as a "
           "click, up estimated.", "segmentation.md"),
    Result("segmentation_elliptic_seeds_25af5a7.json", "segmentation",
           f"{PY} benchmarks/segmentation.py --methods ours --only rubber_tree green_pepper ruby_leaf white_flag_bush "
           "--suite-seeds 5 --out benchmarks/results/segmentation_elliptic_seeds_25af5a7.json",
           "The four elliptic plants at five generator seeds each, with the face-contact rule (25af5a7).",
           "segmentation.md"),
    Result("segmentation_elliptic_seeds.json", "segmentation",
           f"{PY} benchmarks/segmentation.py --methods ours ours_apex --only rubber_tree green_pepper ruby_leaf "
           "white_flag_bush --suite-seeds 5 --out benchmarks/results/segmentation_elliptic_seeds.json",
           "The same five seeds with the apex method beside ours (36dccc4, before the face-contact rule).",
           "segmentation.md"),
    Result("segment_time.json", "segment_time",
           f"{PY} benchmarks/segment_time.py --sizes 100000 --plants 8 --repeats 3; "
           f"{PY} benchmarks/segment_time.py --sizes 1000000 --plants 1 --repeats 3",
           "Whole-process time of leaffit-usd segment at 100k (8 paper8 plants) and 1M (capsicum).",
           "segmentation.md"),
    Result("real_scans.json", "real_scans", f"{PY} benchmarks/real_scans.py",
           "Segmentation on the labelled real scans of ../shared/real (maize scanner, tomato seedling).",
           "segmentation.md"),
    Result("manual.json", "manual", f"{PY} benchmarks/manual.py",
           "Editor picking and tool-update timings, and merged overlap leaves separated by hand "
           "(the edits are replayed from manual_*.edits.json).", "editor.md"),
    Result("deformation_k48.json", "deformation", f"{PY} benchmarks/deformation.py --threads 1 --no-baselines",
           "The paper's Tables 3 and 4 for our fits at the defaults K = 48, reg 0.03 (no baselines).",
           "fitting.md"),
    Result("deformation.json", "deformation", f"{PY} benchmarks/deformation.py --threads 1",
           "Tables 3 and 4 with the baselines (PCA, NR-ICP, CPD), at K = 32 and reg 0.01; ours rerun "
           "with --no-baselines after the outline term.", "fitting.md"),
    Result("fit_time.json", "fit_time", f"{PY} benchmarks/fit_time.py",
           "Registration time and peak memory for the 14-leaf, 100k rubber tree (da0a2f4, K = 32).",
           "fitting.md"),
    Result("render_k48.json", "render", f"{PY} benchmarks/render.py --out benchmarks/results/render_k48.json",
           "Input 3DGS against the converted asset from 8 views (IoU, PSNR, SSIM, surface errors), "
           "13 plants, GT labels, at the defaults K = 48, reg 0.03.", "fitting.md"),
    Result("render_k32_e1ce579.json", "render",
           f"{PY} benchmarks/render.py --work /tmp/r17 --out benchmarks/results/render_k32_e1ce579.json",
           "The same at the former defaults (K = 32, reg 0.01) on an AMD EPYC with AVX2 (e1ce579).", "fitting.md"),
    Result("render_k64.json", "render", f"{PY} benchmarks/render.py -K 64 --out benchmarks/results/render_k64.json",
           "The same with 64 control points per leaf (reg 0.01): measured, not made the default.", "fitting.md"),
    Result("render_k48_reg01.json", "render",
           f"{PY} benchmarks/render.py --convert-with WORKTREE --out benchmarks/results/render_k48_reg01.json",
           "K = 48 with the MLS regulariser at 0.01 (a worktree whose defaults were those).", "fitting.md"),
    Result("render_suite_c0a3847.json", "render",
           f"{PY} benchmarks/render.py --sets suite --out benchmarks/results/render_suite_c0a3847.json "
           "--compare benchmarks/results/render_suite_fe4ab1a.json",
           "Suite plants with the true-surface ceiling (ceil min) and the silhouette alpha of arched strap "
           "leaves (c0a3847).", "fitting.md"),
    Result("render_paper8_c0a3847.json", "render",
           f"{PY} benchmarks/render.py --sets paper8 --out benchmarks/results/render_paper8_c0a3847.json "
           "--compare benchmarks/results/render_paper8_fe4ab1a.json",
           "paper8 seed-1 plants, the same code (c0a3847).", "fitting.md"),
    Result("render_suite_fe4ab1a.json", "render",
           f"{PY} benchmarks/render.py --sets suite --out benchmarks/results/render_suite_fe4ab1a.json "
           "--compare benchmarks/results/render_suite_4e99433.json",
           "Suite plants after convert works on the plant in canonical order (fe4ab1a).", "fitting.md"),
    Result("render_paper8_fe4ab1a.json", "render",
           f"{PY} benchmarks/render.py --sets paper8 --out benchmarks/results/render_paper8_fe4ab1a.json "
           "--compare benchmarks/results/render_paper8_4e99433.json",
           "paper8 plants, the same code (fe4ab1a).", "fitting.md"),
    Result("render_suite_4e99433.json", "render",
           f"{PY} benchmarks/render.py --sets suite --out benchmarks/results/render_suite_4e99433.json",
           "Suite plants after the apex landmark moved to the blade's edge (4e99433).", "fitting.md"),
    Result("render_paper8_4e99433.json", "render",
           f"{PY} benchmarks/render.py --sets paper8 --out benchmarks/results/render_paper8_4e99433.json",
           "paper8 plants, the same code (4e99433).", "fitting.md"),
    Result("render.json", "render",
           f"{PY} benchmarks/render.py --sets suite --work W --out suite.json; the same with --sets paper8; "
           "joined, then printed with --from-json benchmarks/results/render.json",
           "All 13 plants after the template outline's Mip-Splatting filter (e8f97f3).", "fitting.md"),
    Result("render_a8b4436.json", "render",
           f"{PY} benchmarks/render.py --sets suite --work W --out suite.json; the same with --sets paper8; joined",
           "The same two commands on a8b4436, the day before the filter.", "fitting.md"),
    Result("render_before.json", "render",
           f"git worktree add --detach /tmp/before 0a7825d; {PY} benchmarks/render.py --convert-with /tmp/before "
           "--work W --out benchmarks/results/render_before.json",
           "The asset that 0a7825d wrote, before the render-fidelity work, rendered by the current benchmark.",
           "fitting.md"),
    Result("mesh.json", "mesh", f"{PY} benchmarks/mesh.py --methods bpa",
           "Template mesh per sample plant: sheet size, disk topology, distances to points, Gaussians and "
           "the true blade, texture coverage.", "mesh.md"),
    Result("stem_closed_tips.json", "stem",
           f"{PY} benchmarks/stem.py --work /tmp/stem17 --out benchmarks/results/stem_closed_tips.json",
           "Stem surface error against the true tubes (GT labels), with a perfect stem's score and the "
           "lower bound for any stem with closed petiole tips.", "mesh.md"),
    Result("stem_perfect.json", "stem", f"{PY} benchmarks/stem.py --out benchmarks/results/stem_perfect.json",
           "The same with the perfect stem's score, before the closed-tip bound was printed.", "mesh.md"),
    Result("stem.json", "stem", f"{PY} benchmarks/stem.py --work /tmp/stem9/base",
           "Stem surface error, suite and paper8 (the run that fixed the table's figures; busy machine).",
           "mesh.md"),
    Result("size.json", "size", f"{PY} benchmarks/size.py --sets paper8,real",
           "Full convert with defaults of the paper8 plants and the real houseplant: .usdz and "
           ".glb against the input as PLY, SPZ and .splat, the .usdz's parts, validation errors.",
           "scale.md"),
    Result("render_fast_compact.json", "render",
           f"{PY} benchmarks/render.py --plants green_pepper,rubber_tree,golden_pothos,p1_capsicum,p2_soybean "
           "--out benchmarks/results/render_fast_compact.json --compare BEFORE.json",
           "Render fidelity after the Gauss-Newton fit, the texel-density textures and jpg+mask "
           "(rubber tree, paper8 capsicum and soybean).", "render.md"),
    Result("profile_convert.json", "profile_convert", f"{PY} benchmarks/profile_convert.py",
           "Each stage's time and its hot spots (cProfile) for the 100k green pepper, the real "
           "houseplant and the 1M green pepper (busy machine: ratios, not absolute times).",
           "scale.md"),
    Result("scale_seed1_fe4ab1a.json", "scale",
           f"{PY} benchmarks/scale.py --seeds 1 --sizes 100000 1000000 5000000 --labels auto "
           "--out benchmarks/results/scale_seed1_fe4ab1a.json",
           "The seed-1 capsicum at 100k, 1M, 5M Gaussians through convert: wall time, peak memory, leaf "
           "shape error at 10k and 300k surface samples (fe4ab1a, quiet machine).", "scale.md"),
    Result("scale_seeds23_fe4ab1a.json", "scale",
           f"{PY} benchmarks/scale.py --seeds 2 3 --sizes 100000 1000000 --labels auto --eval-spread 0 "
           "--out benchmarks/results/scale_seeds23_fe4ab1a.json",
           "The capsicum of seeds 2 and 3 at 100k and 1M (fe4ab1a).", "scale.md"),
    Result("scale_seed1_4e99433.json", "scale",
           f"{PY} benchmarks/scale.py --seeds 1 --sizes 100000 1000000 --labels auto "
           "--out benchmarks/results/scale_seed1_4e99433.json",
           "Seed 1 at 100k and 1M after the apex landmark change (4e99433; contended wall times).", "scale.md"),
    Result("scale_5m_seed1_4e99433.json", "scale",
           f"{PY} benchmarks/scale.py --seeds 1 --sizes 5000000 --labels auto "
           "--out benchmarks/results/scale_5m_seed1_4e99433.json",
           "Seed 1 at 5M, the same code (4e99433).", "scale.md"),
    Result("scale.json", "scale",
           f"{PY} benchmarks/scale.py --seeds 1 2 3 --sizes 100000 1000000 --labels auto",
           "Seeds 1-3 at 100k (e8f97f3) and 1M (1a24347), quiet machine.", "scale.md"),
    Result("scale_5m.json", "scale",
           f"{PY} benchmarks/scale.py --seeds 1 --sizes 5000000 --labels auto --out benchmarks/results/scale_5m.json",
           "Seed 1 at 5M (1a24347).", "scale.md"),
    Result("read_ply.json", "read_ply", f"{PY} benchmarks/read_ply.py",
           "Reading a 1,000,000-Gaussian SH-3 PLY: time and peak memory in fresh processes.", "formats.md"),
    Result("evaluator.json", "evaluator", f"{PY} benchmarks/evaluator.py --repeats 21 --gl",
           "CPU evaluator and GLSL deformer speed: 1,000 leaves x 2,048 vertices x K = 32.", "api.md"),
    Result("appearance_gltf.json", "appearance_gltf", f"{PY} benchmarks/appearance_gltf.py",
           "GLB through the Khronos validator, both ways, and the per-leaf colour error with and without "
           "the tint (CIE76).", "gltf.md"),
    Result("editing.json", "editing", f"{PY} benchmarks/editing.py",
           "A texture decal made once on the template, per leaf; retargeting across species.", "editor.md"),
    Result("batch.json", "batch",
           f"{PY} benchmarks/batch.py --gaussians 8000 --convert-args \"--steps 40 --refine 3 --bake-size 256 "
           "--texture-size 256\"",
           "leaffit-usd batch on 8 generated plants + a truncated + an empty capture: validation, failures, "
           "jobs scaling, rerun, byte-identity.", "batch.md"),
    Result("render_fast_compact.json", "render",
           f"{PY} benchmarks/render.py --plants green_pepper,rubber_tree,golden_pothos,p1_capsicum,p2_soybean "
           "--out benchmarks/results/render_fast_compact.json --compare BEFORE.json",
           "Render fidelity after the Gauss-Newton fit, the texel-density textures and jpg+mask "
           "(rubber tree, paper8 capsicum and soybean).", "render.md"),
    Result("profile_convert.json", "profile_convert", f"{PY} benchmarks/profile_convert.py",
           "Where a conversion spends its time: each stage's wall time and its hot spots (cProfile).",
           "scale.md"),
)

# results files that are not tables of figures (replayable inputs, text logs): listed, no page
NOT_PAGES = ("manual_hard_horizontal.edits.json", "manual_hard_touching.edits.json",
             "manual_hard_vertical.edits.json", "manual_overlap.edits.json")


# ---------------------------------------------------------------- values

def is_scalar(v) -> bool:
    return v is None or isinstance(v, (str, int, float, bool))


def is_inline_list(v) -> bool:
    return isinstance(v, list) and len(v) <= MAX_INLINE_LIST and all(is_scalar(x) for x in v)


def fmt(v) -> str:
    """One cell: floats to 4 significant digits (no exponent between 1e-4 and 1e5)."""
    if v is None:
        return "–"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v) or math.isinf(v):
            return str(v)
        if v == 0:
            return "0"
        a = abs(v)
        if a >= 1e5 or a < 1e-4:
            return f"{v:.3e}"
        if a >= 1000:
            return f"{v:.1f}"
        return f"{v:.4g}"
    if isinstance(v, list):
        return "[" + ", ".join(fmt(x) for x in v) + "]"
    s = str(v)
    if len(s) > MAX_STRING:
        return f"({len(s)} characters)"
    return s.replace("|", "\\|").replace("\n", " ")


def flatten(d: dict, prefix: str = "") -> tuple[dict, list[str]]:
    """(cells, left_out): scalars and short lists under dotted keys; the keys of longer values."""
    cells, left = {}, []
    for k, v in d.items():
        key = f"{prefix}{k}"
        if is_scalar(v) or is_inline_list(v):
            cells[key] = v
        elif isinstance(v, dict):
            c, l = flatten(v, key + ".")
            cells.update(c)
            left += l
        else:
            left.append(key)
    return cells, left


# ---------------------------------------------------------------- tables

def table(header: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "| " + " | ".join("---" for _ in header) + " |"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return out + [""]


def scalar_table(d: dict) -> list[str]:
    return table(["key", "value"], [[str(k), fmt(v)] for k, v in d.items()])


def dict_rows_table(items: list[tuple[str | None, dict]], key_name: str = "") -> list[str]:
    """A table of flattened dicts (``items``: (row key or None, dict)), split by MAX_COLUMNS."""
    flat, left = [], []
    for _, d in items:
        c, l = flatten(d)
        flat.append(c)
        left += [x for x in l if x not in left]
    columns: list[str] = []
    for c in flat:
        columns += [k for k in c if k not in columns]
    keyed = any(k is not None for k, _ in items)
    # identifying columns: the leading string-valued ones (name, set, plant...), repeated per chunk
    ident = []
    for col in columns:
        if all(isinstance(c.get(col), str) for c in flat) and len(ident) < 2:
            ident.append(col)
        else:
            break
    rest = [c for c in columns if c not in ident]
    chunks = [rest[i:i + MAX_COLUMNS] for i in range(0, len(rest), MAX_COLUMNS)] or [[]]
    out = []
    for chunk in chunks:
        header = ([key_name or "key"] if keyed else []) + ident + chunk
        rows = []
        for (k, _), c in zip(items, flat):
            rows.append(([fmt(k)] if keyed else []) + [fmt(c.get(col)) if col in c else "" for col in ident + chunk])
        out += table(header, rows)
    if left:
        out += ["Per row, not shown (see the JSON): " + ", ".join(f"`{x}`" for x in left) + ".", ""]
    return out


def scalar_lists_table(rows: list[list]) -> list[str]:
    width = max(len(r) for r in rows)
    return table(["#"] + [f"[{i}]" for i in range(width)],
                 [[str(i)] + [fmt(x) for x in r] + [""] * (width - len(r)) for i, r in enumerate(rows)])


def heading(level: int, text: str) -> str:
    return ("#" * level + " " + text) if level <= 4 else f"**{text}**"


def is_table_of_dicts(v) -> bool:
    return isinstance(v, list) and v and all(isinstance(x, dict) for x in v)


def is_dict_of_dicts(v) -> bool:
    return isinstance(v, dict) and v and all(isinstance(x, dict) for x in v.values()) and \
        all(any(is_scalar(y) for y in x.values()) for x in v.values())


def render_value(name: str, v, level: int) -> list[str]:
    out = [heading(level, f"`{name}`"), ""]
    if is_scalar(v) or is_inline_list(v):
        return out + [fmt(v), ""]
    if is_table_of_dicts(v):
        return out + dict_rows_table([(None, x) for x in v])
    if isinstance(v, list) and v and all(isinstance(x, list) and all(is_scalar(y) for y in x) for x in v):
        return out + scalar_lists_table(v)
    if isinstance(v, list):
        if all(is_scalar(x) for x in v):
            nums = [x for x in v if isinstance(x, (int, float)) and not isinstance(x, bool)]
            line = ", ".join(fmt(x) for x in v) if len(v) <= 100 else \
                f"{len(v)} values, {fmt(min(nums))} to {fmt(max(nums))}" if nums else f"{len(v)} values"
            return out + [line, ""]
        return out + [f"{len(v)} entries (see the JSON).", ""]
    if is_dict_of_dicts(v):
        return out + dict_rows_table(list(v.items()))
    return out + render_dict(v, level + 1)


def render_dict(d: dict, level: int) -> list[str]:
    scalars = {k: v for k, v in d.items() if is_scalar(v) or is_inline_list(v)}
    out = scalar_table(scalars) if scalars else []
    for k, v in d.items():
        if k in scalars or k == "machine":
            continue
        out += render_value(k, v, level)
    return out


def machine_block(m: dict) -> list[str]:
    top = {k: v for k, v in m.items() if k != "packages"}
    if isinstance(top.get("isa"), list):
        top["isa"] = " ".join(top["isa"])
    out = ["## Machine", ""] + table(["key", "value"], [[k, fmt(v) if k != "isa" else v] for k, v in top.items()])
    if isinstance(m.get("packages"), dict):
        out += table(["package", "version"], [[k, fmt(v)] for k, v in m["packages"].items()])
    return out


# ---------------------------------------------------------------- pages

def page_name(r: Result) -> str:
    return r.path.replace("/", "_").removesuffix(".json") + ".md"


def render_page(r: Result, data) -> str:
    lines = [f"# `{r.path}`", "",
             f"<!-- generated by `python -m benchmarks.docs` from benchmarks/results/{r.path}; do not edit -->", "",
             r.what, ""]
    if r.topic:
        lines += [f"Benchmark: `benchmarks/{r.benchmark}.py`. What the figures mean: [{r.topic}](../{r.topic}).", ""]
    lines += ["Produced by:", "", "```sh"] + [c.strip() for c in r.command.split("; ")] + ["```", ""]
    if isinstance(data, dict) and isinstance(data.get("machine"), dict):
        lines += machine_block(data["machine"])
    lines += ["## Results", ""]
    if isinstance(data, dict):
        lines += render_dict(data, 3)
    else:
        lines += render_value("results", data, 3)
    while lines and lines[-1] == "":
        lines.pop()
    return "\n".join(lines) + "\n"


def render_index(present: list[Result]) -> str:
    lines = ["# Benchmark results", "",
             "<!-- generated by `python -m benchmarks.docs`; do not edit -->", "",
             "One page per results file in `benchmarks/results/`, generated from it by "
             "`.venv/bin/python -m benchmarks.docs` (a test fails when a page is not current). Each page "
             "gives the command that wrote the file. Within a benchmark the current result comes first; "
             "the others are earlier runs that a docs page compares against. Every benchmark ran on a "
             "shared 2-core CPU machine whose speed varies up to 2x from day to day: read timings within "
             "one file, and the machine block where a file has one.", ""]
    by_bench: dict[str, list[Result]] = {}
    for r in present:
        by_bench.setdefault(r.benchmark, []).append(r)
    rows = []
    for bench, rs in by_bench.items():
        for i, r in enumerate(rs):
            rows.append([f"`benchmarks/{bench}.py`" if i == 0 else "", f"[{r.path}]({page_name(r)})", fmt(r.what),
                         f"[{r.topic}](../{r.topic})" if r.topic else ""])
    lines += table(["benchmark", "results", "what", "explained in"], rows)
    extra = [p for p in NOT_PAGES if (RESULTS_DIR / p).exists()]
    if extra:
        lines += ["Also in `benchmarks/results/`, not pages: "
                  + ", ".join(f"`{p}`" for p in extra)
                  + " (the editor operations `benchmarks/manual.py` replays), `contact_cues.txt` and "
                  "`segmentation.txt` (printed logs), and the template textures `mesh_rubber_tree_*.png`.", ""]
    while lines and lines[-1] == "":
        lines.pop()
    return "\n".join(lines) + "\n"


def unlisted(results_dir: Path = RESULTS_DIR) -> list[str]:
    """Results JSON files with no row in RESULTS (each needs one: its command and what it holds)."""
    known = {r.path for r in RESULTS} | set(NOT_PAGES)
    return sorted(p.relative_to(results_dir).as_posix() for p in results_dir.rglob("*.json")
                  if p.relative_to(results_dir).as_posix() not in known)


def build(results_dir: Path = RESULTS_DIR) -> dict[str, str]:
    """{file name: text} of every page and the index, from the results files that exist."""
    missing = unlisted(results_dir)
    if missing:
        raise SystemExit("benchmarks.docs: no row in RESULTS for " + ", ".join(missing)
                         + " (add its benchmark, command and what it measured)")
    present = [r for r in RESULTS if (results_dir / r.path).exists()]
    pages = {page_name(r): render_page(r, json.loads((results_dir / r.path).read_text())) for r in present}
    pages["index.md"] = render_index(present)
    return pages


def write(out_dir: Path, results_dir: Path = RESULTS_DIR) -> list[Path]:
    """Write every page into ``out_dir``, removing stale ``*.md`` there; returns the paths."""
    pages = build(results_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for old in out_dir.glob("*.md"):
        if old.name not in pages:
            old.unlink()
    paths = []
    for name, text in sorted(pages.items()):
        p = out_dir / name
        if not p.exists() or p.read_text() != text:
            p.write_text(text)
        paths.append(p)
    return paths


def stale(out_dir: Path = DOCS_DIR, results_dir: Path = RESULTS_DIR) -> list[str]:
    """Names of pages in ``out_dir`` that are missing, different or extra."""
    pages = build(results_dir)
    have = {p.name: p.read_text() for p in out_dir.glob("*.md")} if out_dir.exists() else {}
    return sorted({n for n in pages if have.get(n) != pages[n]} | (set(have) - set(pages)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=DOCS_DIR, help="folder of the pages (docs/benchmarks)")
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 when a page is not current")
    args = ap.parse_args(argv)
    if args.check:
        bad = stale(args.out)
        if bad:
            print("not current (run python -m benchmarks.docs): " + ", ".join(bad), file=sys.stderr)
            return 1
        return 0
    paths = write(args.out)
    print(f"{len(paths)} pages in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
