"""``leaffit-usd inspect FILE``: what is in a 3DGS capture (counts, SH degree, bounds, up, height)."""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np

from leaffit_usd.commands import _args
from leaffit_usd.errors import ParameterError
from leaffit_usd.splats.up_axis import LOW_UP_CONFIDENCE

NAME = "inspect"
HELP = "summarise a 3DGS capture (.ply, .compressed.ply, .spz, .sog, .splat, .glb, USD) or a point-cloud scan"
DESCRIPTION = """\
Summarise a 3DGS capture: Gaussian count (and how many invalid ones were dropped), SH degree,
extra properties, bounds, estimated up axis (with a confidence) and plant height, memory size,
opacity and scale statistics, and the file's format. Reads INRIA 3DGS PLY (binary or ASCII),
compressed PLY (PlayCanvas/SuperSplat), SPZ (Niantic), SOG (PlayCanvas: .sog, or an unbundled
meta.json or its folder), .splat (antimatter15), 2DGS and Gaussian Opacity Fields PLY, glTF /
GLB with KHR_gaussian_splatting, USD files holding a UsdVol.ParticleField3DGaussianSplat prim, and
point clouds (PLY x y z [rgb], .xyz / .txt / .pts, .las / .laz: one Gaussian per point, built
from its neighbourhood). Compressed PLY, SPZ and SOG need the optional 'formats' extra (pip
install 'leaffit-usd[formats]'), LAS/LAZ the 'scans' extra (pip install 'leaffit-usd[scans]').

Examples:
  leaffit-usd inspect plant.ply
  leaffit-usd inspect plant.usda --prim /World/Plant --json
  leaffit-usd inspect plant.ply --up +y
"""
ORDER = 90
_MIN_ESTIMATE = 10  # Gaussians needed to estimate an up axis


def add_arguments(parser) -> None:
    parser.add_argument("file", metavar="FILE",
                        help="3DGS capture: .ply, .compressed.ply, .spz, .sog (or meta.json), .splat, "
                             ".glb, .gltf, .usd, .usda, .usdc or .usdz; or a point cloud: .ply, .xyz, "
                             ".txt, .pts, .las or .laz")
    parser.add_argument("--json", action="store_true", help="print a JSON object instead of a table")
    parser.add_argument("--up", default="auto", metavar="AXIS",
                        help="up axis of the capture: auto (estimated, default), +x, -y, z, X,Y,Z "
                             "(e.g. --up -0.1,-1,0)")
    parser.add_argument("--prim", default=None, metavar="PATH",
                        help="USD only: path of the splat prim when the stage holds several")


def _stats(a: np.ndarray) -> dict:
    a = np.asarray(a, np.float64)
    q = np.quantile(a, [0.0, 0.05, 0.5, 0.95, 1.0])
    return {"min": float(q[0]), "p5": float(q[1]), "median": float(q[2]), "p95": float(q[3]),
            "max": float(q[4]), "mean": float(a.mean())}


def summarize(path: str | os.PathLike, prim: str | None = None, up: np.ndarray | None = None,
              cloud=None) -> dict:
    """A JSON-ready summary of the capture at ``path`` (loaded unless ``cloud`` is given).

    up : (3,) unit vector, input frame, or None to estimate it: from the scene as ``convert``
        does (the table, the soil, the pot; source names the cue), else from the plant's shape
        (with a confidence).

    Keys: file, format (key of ``splats.FORMAT_NAMES``), format_name, file_bytes, gaussians,
    dropped, file_gaussians, sh_degree,
    extra_properties {name: dtype}, bounds {min, max, size}, up {vector, source, confidence},
    root {index (file order), position}, height (input units, along up, above the root),
    memory_bytes, opacity {...}, scale {...} (largest axis, linear, input units),
    anisotropy {...} (largest / smallest scale).
    """
    from leaffit_usd.splats import FORMAT_NAMES, detect_format, load_cloud
    from leaffit_usd.splats.frame import make_frame
    from leaffit_usd.splats.up_axis import estimate_up_with_confidence

    path = Path(path)
    kind = detect_format(path)
    if cloud is None:
        cloud = load_cloud(path, prim=prim)
    means = cloud.means
    lo, hi = means.min(0).astype(np.float64), means.max(0).astype(np.float64)
    root_index = None
    if up is not None:
        up_vec, source, conf = np.asarray(up, np.float64), "given", None
    elif len(cloud) < _MIN_ESTIMATE:
        up_vec, source, conf = np.array([0.0, 0.0, 1.0]), "default +z (too few Gaussians to estimate)", 0.0
    else:
        up_vec, source, conf, root_index = _scene_up(cloud)
        if up_vec is None:
            est = estimate_up_with_confidence(means, cloud.shortest_axes())
            up_vec, source, conf = est.up, "estimated from the plant's shape", float(est.confidence)
    try:
        choice = make_frame(cloud, up=up_vec, root_index=root_index)
        root_i, height = choice.root_index, float(choice.frame.height)
    except ParameterError:  # no extent along up (a single Gaussian, a flat sheet across up)
        root_i, height = 0, 0.0
    scales = cloud.scales.astype(np.float64)
    return {
        "file": str(path),
        "format": kind,
        "format_name": FORMAT_NAMES[kind],
        "file_bytes": _size(path),
        "gaussians": len(cloud),
        "dropped": int(cloud.file_count - len(cloud)),
        "file_gaussians": int(cloud.file_count),
        "sh_degree": cloud.sh_degree,
        "extra_properties": {k: str(v.dtype) for k, v in cloud.extra.items()},
        "bounds": {"min": lo.tolist(), "max": hi.tolist(), "size": (hi - lo).tolist()},
        "up": {"vector": [float(x) + 0.0 for x in up_vec], "source": source, "confidence": conf},
        "root": {"index": int(cloud.file_index[root_i]), "position": means[root_i].astype(float).tolist()},
        "height": height,
        "memory_bytes": cloud.nbytes,
        "opacity": _stats(cloud.opacities),
        "scale": _stats(scales.max(1)),
        "anisotropy": _stats(scales.max(1) / np.maximum(scales.min(1), 1e-30)),
    }


def _scene_up(cloud):
    """(up (3,), source, confidence, the stem base's file index or None) from what ``convert``'s
    isolation finds around the plant (the table's normal, the soil disc's, the pot's axis), or
    four Nones."""
    from leaffit_usd.isolate import isolate_plant

    iso = isolate_plant(cloud)
    if iso.up is None:
        return None, None, None, None
    what = {"table": "the table's normal", "soil": "the soil disc's normal", "pot": "the pot's axis"}
    root = None if iso.root_index is None else int(cloud.file_index[iso.root_index])
    return np.asarray(iso.up, np.float64), what.get(iso.up_source, iso.up_source), None, root


def _size(path: Path) -> int:
    """Bytes of a file, or of all files in a folder (an unbundled SOG)."""
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return path.stat().st_size


def _fmt_bytes(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return str(n)


def _vec(v) -> str:
    return "(" + ", ".join(f"{x + 0.0:.4g}" for x in v) + ")"  # + 0.0: no "-0"


def _st(s: dict) -> str:
    return f"min {s['min']:.3g}  median {s['median']:.3g}  p95 {s['p95']:.3g}  max {s['max']:.3g}"


def format_table(s: dict) -> str:
    """The human-readable form of :func:`summarize`'s dict (one ``key  value`` line each)."""
    up = s["up"]
    conf = "" if up["confidence"] is None else f"  (confidence {up['confidence']:.2f}" + (
        ", low: check it or pass --up)" if up["confidence"] < LOW_UP_CONFIDENCE else ")")
    extras = ", ".join(f"{k}:{t}" for k, t in s["extra_properties"].items()) or "none"
    rows = [
        ("file", f"{s['file']}  ({s['format_name']}, {_fmt_bytes(s['file_bytes'])})"),
        ("gaussians", f"{s['gaussians']:,}" + (f"  ({s['dropped']:,} invalid dropped of "
                                                 f"{s['file_gaussians']:,})" if s["dropped"] else "")),
        ("SH degree", f"{s['sh_degree']}  ({(s['sh_degree'] + 1) ** 2} coefficients per channel)"),
        ("extra properties", extras),
        ("bounds min", _vec(s["bounds"]["min"])),
        ("bounds max", _vec(s["bounds"]["max"])),
        ("bounds size", _vec(s["bounds"]["size"])),
        ("up axis", f"{_vec(up['vector'])}  {up['source']}{conf}"),
        ("root (auto)", f"Gaussian {s['root']['index']} at {_vec(s['root']['position'])}"),
        ("height", f"{s['height']:.4g} input units (along up, above the root)"),
        ("memory", _fmt_bytes(s["memory_bytes"])),
        ("opacity", _st(s["opacity"])),
        ("scale (largest axis)", _st(s["scale"])),
        ("anisotropy", _st(s["anisotropy"])),
    ]
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{w}}  {v}" for k, v in rows)


def run(args) -> int:
    summary = summarize(args.file, prim=args.prim, up=_args.parse_up(args.up))
    if args.json:
        sys.stdout.write(json.dumps(summary, indent=2) + "\n")
    else:
        sys.stdout.write(format_table(summary) + "\n")
    return 0
