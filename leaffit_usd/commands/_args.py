"""Argument types and groups shared by several subcommands (frame, segmentation parameters)."""
from __future__ import annotations

import argparse
import math

import numpy as np

from leaffit_usd.errors import ParameterError


def check_image_output(option: str, path) -> None:
    """``path``, a picture the command will write (``--preview``), must name a format
    ``image_io.write_image`` writes. Checked before the work starts: a typo in the suffix costs
    no run and leaves no output behind (ParameterError: exit 2, one line)."""
    from leaffit_usd.image_io import WRITE_FORMATS, image_format

    if image_format(path) not in WRITE_FORMATS:
        raise ParameterError(option, "an image path ending in " + ", ".join("." + f for f in WRITE_FORMATS),
                             str(path))


def pos_int(text):
    """argparse type: an integer >= 0."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {v}")
    return v


def pos_float(text):
    """argparse type: a finite number > 0."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return v


def add_input_argument(p) -> None:
    """The INPUT positional: a 3DGS capture in any format the loader reads."""
    p.add_argument("input", metavar="INPUT",
                   help="3DGS capture: INRIA .ply, .compressed.ply, .spz, .sog, .splat or USD "
                        "ParticleField3DGaussianSplat (see README, input formats)")


def add_frame_arguments(p) -> None:
    """--up, --root, --root-index (the input frame's up direction and the root Gaussian)."""
    g = p.add_argument_group("frame")
    g.add_argument("--up", default="auto",
                   help="the plant's up direction in the input: auto (default), +x, -y, z, or X,Y,Z "
                        "(e.g. --up -y, --up -0.1,-1,0)")
    g.add_argument("--root", default="auto",
                   help="root: auto (lowest point along up) or X,Y,Z in the input frame (nearest "
                        "Gaussian), e.g. --root -1.87,1.50,2.05")
    g.add_argument("--root-index", type=pos_int, default=None, metavar="I",
                   help="root Gaussian's index in the input file")


SEGMENT_FIELDS = ("n_samples", "n_neighbors", "tau", "delta", "epsilon", "rho")


def default(cls, name: str) -> str:
    """The default of dataclass ``cls``'s field ``name``, as help text shows it (one source)."""
    import dataclasses

    f = {f.name: f for f in dataclasses.fields(cls)}[name]
    v = f.default_factory() if f.default is dataclasses.MISSING else f.default
    return f"{v:g}" if isinstance(v, float) else str(v)


def add_segment_arguments(p, title="segmentation (paper defaults, working units: plant height 1)"):
    """The automatic segmentation's parameters; read back with :func:`segment_params`."""
    from leaffit_usd.segment.auto import SegmentParams

    def d(name):
        return default(SegmentParams, name)

    g = p.add_argument_group(title)
    g.add_argument("--n-samples", type=pos_int, help=f"N_s, farthest point samples ({d('n_samples')})")
    g.add_argument("--n-neighbors", type=pos_int, help=f"N_k, neighbours of the apex test ({d('n_neighbors')})")
    g.add_argument("--tau", type=pos_float, help=f"tau, apex grouping margin ({d('tau')})")
    g.add_argument("--delta", type=pos_float, help=f"delta, iso-geodesic band width ({d('delta')})")
    g.add_argument("--epsilon", type=pos_float, help=f"epsilon, petiole diameter threshold ({d('epsilon')})")
    g.add_argument("--rho", type=float, help=f"rho, early protection ratio ({d('rho')})")
    g.add_argument("--orientation", action="store_true",
                   help="orientation-aware geodesics: no short-cut between a Gaussian and points off its "
                        "tangent plane (a leaf lying on another); off by default")
    g.add_argument("--method", choices=("blades", "apex"),
                   help="blades (default): leaves are sheets and the stem tubes, told apart by the "
                        "Gaussians' normals (leaffit_usd.segment.blades); apex: the paper's apex -> "
                        "tree -> petiole march with our fixes (the N_s ... rho options apply to it)")
    g.add_argument("--paper-rules", action="store_true",
                   help="the paper's algorithm exactly: the apex method with all N_k Euclidean "
                        "neighbours voting in the apex test, no blade-first / base refinement / "
                        "LCA-on-blade rules, absolute tau only, epsilon alone for the petiole, "
                        "blade-less instances kept (see leaffit_usd.segment.auto)")
    return g


def segment_params(args, **fields):
    """The validated ``SegmentParams`` of the arguments :func:`add_segment_arguments` added
    (``fields``: further overrides, e.g. seed)."""
    from leaffit_usd.segment.auto import SegmentParams

    return SegmentParams(**_segment_overrides(args), **fields).validate()


def _segment_overrides(args) -> dict:
    """SegmentParams field overrides from the arguments :func:`add_segment_arguments` added."""
    kw = {k: getattr(args, k) for k in SEGMENT_FIELDS if getattr(args, k, None) is not None}
    if getattr(args, "orientation", False):
        kw["orientation_aware"] = True
    if getattr(args, "method", None):
        kw["method"] = args.method
    if getattr(args, "paper_rules", False):
        from dataclasses import fields

        from leaffit_usd.segment.auto import SegmentParams

        paper = SegmentParams.paper()
        base = SegmentParams()
        kw.update({f.name: getattr(paper, f.name) for f in fields(SegmentParams)
                   if getattr(paper, f.name) != getattr(base, f.name)})
    return kw


AXES = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1)}


def parse_up(text: str | None) -> np.ndarray | None:
    """--up: 'auto' or None -> None (estimate it); '+y', '-z', 'y' or 'X,Y,Z' -> (3,) float64
    unit vector, input frame. Raises ParameterError."""
    t = "auto" if text is None else str(text).strip().lower()
    if t == "auto":
        return None
    sign = -1.0 if t.startswith("-") else 1.0
    key = t.lstrip("+-")
    if key in AXES:
        return sign * np.asarray(AXES[key], dtype=np.float64)
    try:
        v = np.asarray([float(c) for c in t.split(",")], dtype=np.float64)
    except ValueError:
        raise ParameterError("--up", "an axis (+x, -y, z ...) or a vector X,Y,Z", text) from None
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) < 1e-12:
        raise ParameterError("--up", "a non-zero vector X,Y,Z", text)
    return v / np.linalg.norm(v)


def parse_root(text: str | None) -> np.ndarray | None:
    """--root: 'auto' or None -> None (the lowest point along up); 'X,Y,Z' -> (3,) float64 point,
    input frame. Raises ParameterError."""
    t = "auto" if text is None else str(text).strip().lower()
    if t in ("", "auto"):
        return None
    try:
        xyz = np.asarray([float(c) for c in t.split(",")], np.float64)
    except ValueError:
        raise ParameterError("--root", "'auto' or a point X,Y,Z in the input frame", text) from None
    if xyz.shape != (3,) or not np.isfinite(xyz).all():
        raise ParameterError("--root", "'auto' or a point X,Y,Z in the input frame", text)
    return xyz


def frame_options(args) -> dict:
    """``make_frame`` keywords (up, root, root_index) from :func:`add_frame_arguments`' arguments."""
    return dict(up=parse_up(args.up), root=parse_root(args.root), root_index=args.root_index)


def add_isolate_arguments(p, with_keep_scene: bool = True):
    """--keep-scene, --crop: plant isolation (table, pot, soil, background, floaters)."""
    g = p.add_argument_group("isolation (what a real capture keeps around the plant)")
    if with_keep_scene:
        g.add_argument("--keep-scene", action="store_true",
                       help="skip plant isolation (the input is already a trimmed plant); --crop still applies")
    g.add_argument("--crop", metavar="REGION", default=None,
                   help="keep only a region of the input frame: box:X0,Y0,Z0,X1,Y1,Z1 or sphere:CX,CY,CZ,R "
                        "(input frame)")
    return g
