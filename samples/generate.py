"""Procedural 3DGS plants with ground truth.

    python -m samples.generate --kind lobed --leaves 12 --seed 3 --out out/ --name my_plant
    python -m samples.generate --preset rubber_tree --out samples/plants
    python -m samples.generate --suite --out out/suite        # the benchmark suite

Canonical frame: metres, root (stem base, on the stem axis) at the origin, up +Z. The written
PLY is in the *input frame*: the canonical plant mapped by a random similarity (rotation, scale,
offset; ``GroundTruth.canonical_to_input``), as an SfM reconstruction would place it.

Labels (``GroundTruth.labels``, file order): 0 = stem, branches and petioles; 1..L = leaf
blades; -1 = floaters. The label boundary between petiole and blade is the **blade base**: the
point where the blade outline meets the midrib (for cordate/palmate blades the basal sinus).
Everything sampled on the petiole tube (node -> blade base) is 0; everything sampled on the
blade sheet is the leaf's label. ``leaf_base`` is that point, ``leaf_apex`` the main apex.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from leaffit_usd.geometry.normals import vertex_normals
from leaffit_usd.geometry.quaternion import matrix_to_quat
from leaffit_usd.io_util import atomic_path
from leaffit_usd.splats.cloud import SH_C0, GaussianCloud
from leaffit_usd.splats.ply import write_ply

from samples.capture import FLOATERS as CAPTURE_FLOATERS
from samples.capture import LAYER_NOISE, POT_KINDS, REALISMS, LeafSites
from samples.leaves import (KIND_SHAPES, SHAPES, LeafShapeParams, LeafSheet, make_outline,
                            make_sheet, vein_field)

log = logging.getLogger("leaffit_usd")

KINDS = ("elliptic", "lobed", "thin", "cordate", "mixed")
OVERLAPS = ("none", "touching", "vertical", "horizontal", "all")
HABITS = ("shrub", "rosette", "cane")


# ---------------------------------------------------------------------------------------------
# specification
# ---------------------------------------------------------------------------------------------

@dataclass
class PlantSpec:
    """What to generate. ``None`` fields are drawn from the seed (per-kind ranges).

    kind : leaf family: elliptic | lobed | thin | cordate | mixed (every leaf its own family)
    leaves : number of leaf blades L (labels 1..L)
    gaussians : total number of Gaussians (stem + leaves + floaters)
    sh_degree : 0..3 (DC colour set; higher bands small noise)
    overlap : none | touching | vertical | horizontal | all — pairs of leaves built to touch
        (margins ~1 mm apart, side by side), to stack vertically (upper blade a few mm above the
        lower one) or to overlap side-on (one blade partly over its neighbour)
    shape : force one outline preset (see ``samples.leaves.SHAPES``)
    serration : margin tooth depth (blade lengths), None = per-kind random
    habit : shrub (stem + branches + side shoots) | rosette (crown + long petioles) | cane
    height : approximate plant height, metres (canonical frame); None = random 0.3-1.2
    branches, side_shoots : counts; None = random
    floaters : fraction of Gaussians that are floaters (label -1); None = 0.003 (ideal) or
        ``samples.capture.FLOATERS`` (capture)
    surface_noise : typical std (metres) of blade Gaussians off the surface; each leaf draws its
        own level around it (x0.2..x3), 4 % of Gaussians get 4x that
    fuzz : fraction of blade Gaussians floating 0-8 mm off the surface (large, faint)
    holes : fraction of leaves with a poorly reconstructed patch (almost no Gaussians there;
        their GT mesh stays complete)
    variation : per-leaf shape/size variation scale (0 = identical leaves)
    palette : front colour RGB in [0, 1]; None = per-kind green
    glossy : strength of the view-dependent (higher SH band) noise on leaf fronts
    variegation : 0..1, yellow-cream streaks on the blades (golden pothos)
    spots : fraction of leaves with a few brown spots (damage, age)
    global_frame : apply a random similarity (input frame != canonical frame)
    hard : marks a deliberately difficult plant (set automatically when overlap != none)
    scene : the surroundings a capture keeps (GT label -2, their class in
        ``GroundTruth.scene_class``): True = a pot, soil, a table top, clutter, a back wall and
        scene floaters (``samples.scene``; about as many Gaussians again as ``gaussians``);
        "pot" = a pot with soil and a few floaters round it, nothing else (a capture with the
        background removed; ``samples.capture.make_pot_scene``, ~0.7x ``gaussians`` more);
        False = the plant alone; None = False (ideal) or "pot" (capture)
    realism : "ideal" (clean, nearly opaque discs on the surface) | "capture" (the statistics
        of a trained 3DGS capture: faint logit-normal opacities, needles, thick discs with
        noisy normals, 2-3 layers per leaf, edge fuzz, more floaters; ``samples.capture``)
    pot : "ceramic" (white) | "terracotta" | "plastic"; None = drawn from the seed
    """

    kind: str = "elliptic"
    leaves: int = 14
    gaussians: int = 100_000
    sh_degree: int = 0
    overlap: str = "none"
    shape: str | None = None
    serration: float | None = None
    habit: str | None = None
    height: float | None = None
    branches: int | None = None
    side_shoots: int | None = None
    floaters: float | None = None
    holes: float = 0.15
    surface_noise: float = 0.0006
    fuzz: float = 0.02
    variation: float = 1.0
    palette: tuple | None = None
    glossy: float = 0.5
    variegation: float = 0.0
    spots: float = 0.2
    petiole_ratio: float | None = None
    leaf_length: float | None = None
    global_frame: bool = True
    hard: bool = False
    scene: bool | str | None = None
    realism: str = "ideal"
    pot: str | None = None

    def __post_init__(self):
        if self.realism not in REALISMS:
            raise ValueError(f"realism must be one of {REALISMS}, got {self.realism!r}")
        if self.pot is not None and self.pot not in POT_KINDS:
            raise ValueError(f"pot must be one of {POT_KINDS} or None, got {self.pot!r}")
        capture = self.realism == "capture"
        if self.scene is None:
            self.scene = "pot" if capture else False
        if self.scene not in (False, True, "pot"):
            raise ValueError(f"scene must be False, True or 'pot', got {self.scene!r}")
        if self.floaters is None:
            self.floaters = CAPTURE_FLOATERS if capture else 0.003
        if not 0 <= float(self.floaters) < 0.5:
            raise ValueError(f"floaters must be a fraction in [0, 0.5), got {self.floaters}")
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")
        if self.overlap not in OVERLAPS:
            raise ValueError(f"overlap must be one of {OVERLAPS}, got {self.overlap!r}")
        if self.habit is not None and self.habit not in HABITS:
            raise ValueError(f"habit must be one of {HABITS}, got {self.habit!r}")
        if self.shape is not None and self.shape not in SHAPES:
            raise ValueError(f"shape must be one of {sorted(SHAPES)}, got {self.shape!r}")
        if not 1 <= int(self.leaves) <= 200:
            raise ValueError(f"leaves must be in 1..200, got {self.leaves}")
        if not 0 <= int(self.sh_degree) <= 3:
            raise ValueError(f"sh_degree must be 0..3, got {self.sh_degree}")
        if int(self.gaussians) < 200 * int(self.leaves):
            raise ValueError(f"gaussians must be at least 200 per leaf, got {self.gaussians}")
        if self.palette is not None:
            self.palette = tuple(float(c) for c in self.palette)
        if self.overlap != "none":
            self.hard = True

    def to_dict(self) -> dict:
        """The fields as a JSON-ready dict; ``realism`` and ``pot`` only when not at their
        defaults (the ground truth of an ideal plant keeps the bytes it had before they existed)."""
        d = dataclasses.asdict(self)
        for name, default in (("realism", "ideal"), ("pot", None)):
            if d[name] == default:
                del d[name]
        return d

    @staticmethod
    def from_dict(d: dict) -> "PlantSpec":
        names = {f.name for f in dataclasses.fields(PlantSpec)}
        return PlantSpec(**{k: v for k, v in d.items() if k in names})


# Species-like presets (kwargs for PlantSpec). Leaf counts follow the paper's dataset.
PRESETS: dict[str, dict] = {
    "rubber_tree": dict(kind="elliptic", shape="rubber", leaves=14, habit="shrub", height=0.7,
                        palette=(0.09, 0.22, 0.07), glossy=0.9, petiole_ratio=0.22,
                        leaf_length=0.17),
    "cotton_rose": dict(kind="lobed", shape="cotton_rose", leaves=12, habit="shrub", height=0.75,
                        palette=(0.22, 0.40, 0.13), glossy=0.2, petiole_ratio=0.75,
                        leaf_length=0.11, serration=0.012),
    "lucky_bamboo": dict(kind="thin", shape="linear", leaves=11, habit="cane", height=0.45,
                         palette=(0.25, 0.50, 0.12), glossy=0.6, petiole_ratio=0.15,
                         leaf_length=0.19),
    "golden_pothos": dict(kind="cordate", shape="cordate", leaves=5, habit="shrub", height=0.35,
                          palette=(0.24, 0.45, 0.10), glossy=0.7, petiole_ratio=0.7,
                          leaf_length=0.11, variegation=0.35),
    "green_pepper": dict(kind="elliptic", shape="ovate", leaves=9, habit="shrub", height=0.5,
                         palette=(0.16, 0.36, 0.10), glossy=0.4, leaf_length=0.1),
    "black_pearl_pepper": dict(kind="thin", shape="lanceolate", leaves=11, habit="shrub",
                               height=0.45, palette=(0.10, 0.07, 0.11), glossy=0.6,
                               leaf_length=0.09),
    "ruby_leaf": dict(kind="elliptic", shape="obovate", leaves=7, habit="rosette", height=0.35,
                      palette=(0.35, 0.08, 0.12), glossy=0.5, leaf_length=0.12),
    "white_flag_bush": dict(kind="elliptic", shape="elliptic", leaves=27, habit="rosette",
                            height=0.6, palette=(0.12, 0.30, 0.08), glossy=0.7, leaf_length=0.16),
    "maple_seedling": dict(kind="lobed", shape="maple", leaves=8, habit="shrub", height=0.55,
                           palette=(0.20, 0.38, 0.10), serration=0.025, leaf_length=0.09,
                           petiole_ratio=0.8),
}

_KIND_DEFAULTS = {
    # habit, leaf length range (m), petiole/blade ratio range, front colour
    "elliptic": ("shrub", (0.09, 0.2), (0.15, 0.45), (0.12, 0.30, 0.08)),
    "lobed": ("shrub", (0.07, 0.13), (0.5, 1.0), (0.20, 0.38, 0.12)),
    "thin": ("cane", (0.12, 0.24), (0.05, 0.15), (0.22, 0.45, 0.11)),
    "cordate": ("shrub", (0.07, 0.14), (0.45, 0.9), (0.20, 0.40, 0.10)),
    "mixed": ("shrub", (0.08, 0.18), (0.2, 0.7), (0.15, 0.35, 0.10)),
}


# ---------------------------------------------------------------------------------------------
# ground truth
# ---------------------------------------------------------------------------------------------

@dataclass
class GroundTruth:
    """Ground truth of one generated plant (input frame unless stated).

    labels : (N,) int32, file order; 0 stem/branches/petioles, 1..L leaf blades, -1 floaters
    petiole_of : (N,) int32, file order; j for a Gaussian on leaf j's petiole (label 0), else 0
    root : (3,) float64, stem base on the stem axis
    root_index : int, the stem Gaussian nearest to ``root``
    up : (3,) float64 unit vector
    height : float, plant height along ``up`` above the root (Frame.from_root_up's formula over
        all non-floater Gaussians), input units
    leaf_vertices : (V, 3) float32, GT blade meshes of all leaves concatenated
    leaf_faces : (F, 3) int32, indices into leaf_vertices; CCW seen from the upper (adaxial)
        side, i.e. face normals point to the upper side
    leaf_vertex_ids : (V,) int32, leaf label (1..L) of each vertex
    leaf_apex, leaf_base : (L, 3) float64, main apex / blade base (petiole-blade junction) of
        leaf j at row j-1
    leaf_node : (L, 3) float64, where the leaf's petiole leaves its stem axis
    overlap_pairs : (P, 2) int32, leaf label pairs built to touch/overlap (empty if none)
    overlap_types : (P,) int32: 1 touching, 2 vertical, 3 horizontal
    overlap_gaps : (P,) float64, smallest distance between the pair's GT blade meshes, input units
    canonical_to_input : (4, 4) float64 similarity, canonical (metres, root at 0, +Z up) -> input
    spec : JSON string: {"spec": PlantSpec fields, "seed": int, "leaves": per-leaf info,
        "scene": the surroundings' layout when ``spec.scene``}
    scene_class : (N,) int8, file order, or None for a plant without surroundings: 0 plant
        (labels >= 0), 1 ground (table), 2 pot, 3 soil, 4 background, 5 floater (the
        ``leaffit_usd.isolate`` class codes); scene Gaussians have ``labels`` -2
    stem_samples : (S, 3) float64, points drawn uniformly by area on the exact tube surfaces of
        the stem, branches and petioles (what a stem mesh is scored against); empty in files
        written before it existed
    """

    labels: np.ndarray
    petiole_of: np.ndarray
    root: np.ndarray
    root_index: int
    up: np.ndarray
    height: float
    leaf_vertices: np.ndarray
    leaf_faces: np.ndarray
    leaf_vertex_ids: np.ndarray
    leaf_apex: np.ndarray
    leaf_base: np.ndarray
    leaf_node: np.ndarray
    overlap_pairs: np.ndarray
    overlap_types: np.ndarray
    overlap_gaps: np.ndarray
    canonical_to_input: np.ndarray
    spec: str
    scene_class: np.ndarray | None = None
    stem_samples: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def n_leaves(self) -> int:
        return int(len(self.leaf_apex))

    @property
    def scale(self) -> float:
        """Input units per metre."""
        return float(np.cbrt(abs(np.linalg.det(self.canonical_to_input[:3, :3]))))

    def leaf_mesh(self, label: int):
        """(V_j, 3) float32 vertices, (F_j, 3) int64 faces of leaf ``label`` (local indices)."""
        sel = np.flatnonzero(self.leaf_vertex_ids == label)
        remap = np.full(len(self.leaf_vertices), -1, np.int64)
        remap[sel] = np.arange(len(sel))
        f = remap[self.leaf_faces]
        f = f[(f >= 0).all(1)]
        return self.leaf_vertices[sel], f

    def spec_dict(self) -> dict:
        return json.loads(self.spec)


_OPTIONAL_GT = ("scene_class", "stem_samples")


def save_plant(cloud: GaussianCloud, gt: GroundTruth, directory, name: str) -> tuple[Path, Path]:
    """Write ``NAME.ply`` (INRIA 3DGS) and ``NAME.gt.npz`` into ``directory``, atomically."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    ply, gtp = d / f"{name}.ply", d / f"{name}.gt.npz"
    write_ply(cloud, ply)
    arrays = {f.name: np.asarray(getattr(gt, f.name)) for f in dataclasses.fields(gt)
              if getattr(gt, f.name) is not None}
    arrays["spec"] = np.array(gt.spec)
    with atomic_path(gtp) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return ply, gtp


def load_ground_truth(path) -> GroundTruth:
    """Read a ``NAME.gt.npz`` written by :func:`save_plant`.

    Raises ``InputFileError`` when the file is missing, not an npz, or lacks a field.
    """
    from leaffit_usd.errors import InputFileError

    path = Path(path)
    if not path.is_file():
        raise InputFileError(path, "no such file")
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise InputFileError(path, f"not a ground-truth .npz ({e})") from None
    with z:
        missing = [f.name for f in dataclasses.fields(GroundTruth)
                   if f.name not in z.files and f.name not in _OPTIONAL_GT]
        if missing:
            raise InputFileError(path, f"not a samples ground-truth file: missing {', '.join(missing)}")
        kw = {}
        for f in dataclasses.fields(GroundTruth):
            if f.name not in z.files:
                continue
            v = z[f.name]
            if f.name == "spec":
                v = str(v)
            elif f.name == "root_index":
                v = int(v)
            elif f.name == "height":
                v = float(v)
            kw[f.name] = v
    return GroundTruth(**kw)


# ---------------------------------------------------------------------------------------------
# plant structure
# ---------------------------------------------------------------------------------------------

@dataclass
class Axis:
    """A stem/branch/petiole tube: centreline (K, 3) and radius (K,), canonical frame, metres."""

    pts: np.ndarray
    radius: np.ndarray
    kind: str = "stem"
    internode: float = 0.0      # > 0: draw node rings every ``internode`` metres (canes)

    def __post_init__(self):
        seg = np.linalg.norm(np.diff(self.pts, axis=0), axis=1)
        self.s = np.concatenate([[0.0], np.cumsum(seg)])

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def at(self, t):
        """Point, unit tangent and radius at arclength fraction t in [0, 1]."""
        s = np.clip(t, 0, 1) * self.length
        p = np.array([np.interp(s, self.s, self.pts[:, k]) for k in range(3)])
        i = int(np.clip(np.searchsorted(self.s, s) - 1, 0, len(self.pts) - 2))
        tan = self.pts[i + 1] - self.pts[i]
        return p, tan / np.linalg.norm(tan), float(np.interp(s, self.s, self.radius))


def _curve(p0, d0, length, rng, k=24, bend=0.0, wobble=0.02, up_pull=0.0):
    """A gently curved centreline from p0 along d0 (bending towards +Z by ``up_pull``)."""
    d = np.asarray(d0, float) / np.linalg.norm(d0)
    pts = [np.asarray(p0, float)]
    step = length / (k - 1)
    side = rng.normal(0, 1, 3)
    for i in range(1, k):
        d = d + up_pull * np.array([0, 0, 1.0]) * step / max(length, 1e-9) + \
            wobble * rng.normal(0, 1, 3) * np.sqrt(step / max(length, 1e-9)) + bend * side * step / length
        d /= np.linalg.norm(d)
        pts.append(pts[-1] + d * step)
    return np.array(pts)


def _dir(az, el):
    return np.array([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.sin(el)])


def _bezier(p0, p1, p2, p3, k=16):
    t = np.linspace(0, 1, k)[:, None]
    return ((1 - t) ** 3) * p0 + 3 * ((1 - t) ** 2) * t * p1 + 3 * (1 - t) * t * t * p2 + t ** 3 * p3


@dataclass
class LeafPlacement:
    axis: int
    t: float
    az: float
    el_pet: float       # petiole elevation
    el_blade: float     # blade base elevation
    roll: float
    pet_len: float
    node: np.ndarray = None

    def frame(self):
        x = _dir(self.az, self.el_blade)
        y = np.cross([0, 0, 1.0], x)
        y /= np.linalg.norm(y)
        z = np.cross(x, y)
        c, s = np.cos(self.roll), np.sin(self.roll)
        y, z = c * y + s * z, -s * y + c * z
        return np.stack([x, y, z], 1)

    def blade_base(self):
        return self.node + self.pet_len * _dir(self.az, self.el_pet)


@dataclass
class _Leaf:
    sheet: LeafSheet
    place: LeafPlacement
    label: int
    colour_front: np.ndarray
    colour_back: np.ndarray
    density: float
    back_fraction: float
    vein_phase: float
    n_secondary: int
    pet_radius: float
    hole: tuple | None = None   # (centre (2,), radius) in leaf 2D units: a sparse patch
    spots: list = field(default_factory=list)  # [(centre (2,), radius)] brown spots, leaf 2D

    def world(self):
        R = self.place.frame()
        return self.sheet.local @ R.T + (self.place.blade_base() - R @ self.sheet.base)

    def to_world(self, p):
        R = self.place.frame()
        return np.asarray(p) @ R.T + (self.place.blade_base() - R @ self.sheet.base)


def _leaf_params(shape: str, length: float, rng, variation: float, habit: str) -> LeafShapeParams:
    v = variation
    fam = SHAPES[shape]["family"]
    thin = SHAPES[shape]["venation"] == "parallel"
    prm = LeafShapeParams(
        length=length,
        fold=float(np.clip(rng.normal(0.25 if thin else 0.12, 0.08 * v + 1e-6), -0.05, 0.6)),
        cup=float(rng.normal(0.15, 0.25 * v)),
        droop=float(rng.normal(0.9 if thin else 0.35, 0.3 * v)),
        droop2=float(np.abs(rng.normal(1.2 if thin else 0.35, 0.35 * v))),
        twist=float(rng.normal(0.0, (0.6 if thin else 0.2) * v)),
        lateral=float(rng.normal(0.0, (0.25 if thin else 0.05) * v)),
        wave_amp=float(abs(rng.normal(0.0, 0.012 * v)) * (rng.uniform() < 0.6)),
        wave_freq=float(rng.integers(4, 11)),
        wave_phase=float(rng.uniform(0, 2 * np.pi)),
    )
    if fam == "palmate":
        prm.droop *= 0.5
        prm.fold *= 0.5
        prm.cup = float(rng.normal(-0.05, 0.15 * v))  # palmate blades dome a little
    return prm


def _build(spec: PlantSpec, rng: np.random.Generator):
    """Skeleton axes + placed leaves, canonical frame."""
    kd = _KIND_DEFAULTS[spec.kind]
    habit = spec.habit or kd[0]
    H = spec.height if spec.height is not None else float(rng.uniform(0.35, 1.0))
    L = int(spec.leaves)
    leaf_len = spec.leaf_length or float(rng.uniform(*kd[1])) * float(np.clip((H / 0.6) ** 0.5, 0.8, 1.3))
    # leaf length vs plant height: keep a plant plausible (leaves not longer than ~45 % of H)
    leaf_len = min(leaf_len, 0.45 * H)
    pet_ratio = spec.petiole_ratio if spec.petiole_ratio is not None else float(rng.uniform(*kd[2]))
    if habit == "rosette":
        pet_ratio = max(pet_ratio, 1.2) * float(rng.uniform(1.0, 1.6))

    axes: list[Axis] = []
    # ---- main stem
    if habit == "rosette":
        stem_h = float(rng.uniform(0.03, 0.06))
        r0 = float(rng.uniform(0.008, 0.014))
    elif habit == "cane":
        stem_h = H * float(rng.uniform(0.5, 0.7))
        r0 = float(rng.uniform(0.007, 0.011))
    else:
        stem_h = H * float(rng.uniform(0.55, 0.8))
        r0 = float(rng.uniform(0.003, 0.006)) * (H / 0.6) ** 0.5
    lean = rng.normal(0, 0.12 if habit != "cane" else 0.05, 2)
    main = _curve([0, 0, 0], [lean[0], lean[1], 1.0], stem_h, rng, k=32, wobble=0.05,
                  up_pull=0.1)
    taper = 1.0 - (0.55 if habit == "shrub" else 0.15) * np.linspace(0, 1, len(main)) ** 1.2
    axes.append(Axis(main, r0 * taper, "stem",
                     internode=float(rng.uniform(0.04, 0.07)) if habit == "cane" else 0.0))

    # ---- allocate leaves to axes
    n_br = spec.branches if spec.branches is not None else (
        0 if habit == "rosette" or L < 6 else int(rng.integers(1, 3 if L < 15 else 4)))
    n_sh = spec.side_shoots if spec.side_shoots is not None else (
        0 if habit == "rosette" or L < 5 else int(rng.integers(0, 3)))
    if habit == "rosette":
        n_br = n_sh = 0
    shoot_leaves = [int(rng.integers(1, 3)) for _ in range(n_sh)]
    while sum(shoot_leaves) > max(0, L - 3):
        shoot_leaves.pop()
    rest = L - sum(shoot_leaves)
    br_leaves = []
    for _ in range(n_br):
        k = int(round(rest * float(rng.uniform(0.15, 0.3))))
        if k >= 2 and rest - k >= 3:
            br_leaves.append(k)
            rest -= k
    main_leaves = rest

    slots: list[tuple[int, float]] = []  # (axis, t)
    if habit == "rosette":
        slots += [(0, float(t)) for t in np.linspace(0.5, 1.0, main_leaves)]
    elif habit == "cane":
        slots += [(0, float(t)) for t in np.sort(rng.uniform(0.8, 1.0, main_leaves))]
    else:
        ts = np.linspace(0.35, 1.0, main_leaves) ** 0.8 if main_leaves > 1 else np.array([1.0])
        slots += [(0, float(np.clip(t + rng.normal(0, 0.02), 0.2, 1.0))) for t in ts]

    def add_axis(t0, length, el, az, r_rel, kind="stem", pull=0.6):
        p, _tan, r = axes[0].at(t0)
        pts = _curve(p, _dir(az, el), length, rng, k=20, wobble=0.04, up_pull=pull)
        rr = r * r_rel * (1 - 0.5 * np.linspace(0, 1, len(pts)))
        axes.append(Axis(pts, rr, kind))
        return len(axes) - 1

    for k in br_leaves:
        t0 = float(rng.uniform(0.25, 0.6)) if habit != "cane" else float(rng.uniform(0.2, 0.7))
        # branch length grows with the leaves it carries (no long bare branches)
        ln = H * float(rng.uniform(0.1, 0.2)) * float(np.clip(np.sqrt(k / 2.0), 1.0, 2.0))
        a = add_axis(t0, ln, float(rng.uniform(0.5, 1.0)), float(rng.uniform(0, 2 * np.pi)), 0.6)
        slots += [(a, float(t)) for t in np.linspace(0.25, 1.0, k) + rng.normal(0, 0.03, k)]
    for k in shoot_leaves:
        t0 = float(rng.uniform(0.3, 0.9))
        ln = float(rng.uniform(0.03, 0.08))
        a = add_axis(t0, ln, float(rng.uniform(0.3, 0.9)), float(rng.uniform(0, 2 * np.pi)), 0.45,
                     pull=0.3)
        slots += [(a, float(t)) for t in np.linspace(0.7, 1.0, k)]

    # ---- leaf shapes and placements
    golden = np.deg2rad(137.508)
    leaves: list[_Leaf] = []
    az0 = float(rng.uniform(0, 2 * np.pi))
    per_axis_count: dict[int, int] = {}
    serr_default = {"lobed": 0.015, "elliptic": 0.0, "thin": 0.0, "cordate": 0.0, "mixed": 0.0}
    for j, (ai, t) in enumerate(slots):
        if spec.shape:
            shape = spec.shape
        elif spec.kind == "mixed":
            shape = str(rng.choice(sorted(s for v in KIND_SHAPES.values() for s in v)))
        else:
            shape = str(rng.choice(KIND_SHAPES[spec.kind]))
        serr = spec.serration if spec.serration is not None else (
            serr_default[spec.kind] * float(rng.uniform(0.0, 2.0)) if rng.uniform() < 0.5 else 0.0)
        outline = make_outline(shape, rng, serration=serr, variation=spec.variation)
        young = 1.0 - 0.35 * max(0.0, (t - 0.85) / 0.15) if ai == 0 and habit == "shrub" else 1.0
        length = leaf_len * young * float(np.exp(rng.normal(0, 0.12 * spec.variation)))
        if SHAPES[shape]["family"] == "palmate":
            length *= 0.8  # base->apex of a palmate blade is shorter than its span
        prm = _leaf_params(shape, length, rng, spec.variation, habit)
        sheet = make_sheet(outline, prm)
        n = per_axis_count.get(ai, 0)
        per_axis_count[ai] = n + 1
        az = az0 + ai * 1.3 + n * golden + rng.normal(0, 0.15)
        if habit == "rosette":
            el_p = float(rng.uniform(0.7, 1.25))
            el_b = el_p - float(rng.uniform(0.3, 0.7))
        elif habit == "cane":
            el_p = float(rng.uniform(0.5, 1.1))
            el_b = el_p - float(rng.uniform(0.0, 0.3))
        else:
            el_p = float(rng.uniform(0.35, 0.9))
            el_b = el_p - float(rng.uniform(0.3, 0.8))
        pet = max(0.008, length * pet_ratio * float(np.exp(rng.normal(0, 0.15))))
        pl = LeafPlacement(axis=ai, t=t, az=float(az), el_pet=el_p, el_blade=el_b,
                           roll=float(rng.normal(0, 0.2)), pet_len=pet)
        p, tan, r = axes[ai].at(t)
        pl.node = p
        pal = np.array(spec.palette if spec.palette is not None else kd[3])
        front = np.clip(pal * np.exp(rng.normal(0, 0.08, 3)) * float(np.exp(rng.normal(0, 0.1))), 0, 1)
        if young < 1.0:  # young leaves at the top: lighter, yellower
            front = np.clip(front + (1.0 - young) * 1.2 * (np.array([0.45, 0.6, 0.15]) - front), 0, 1)
        # the abaxial side: lighter, duller, a little grey-blue
        back = np.clip(0.5 * front + 0.5 * np.array([0.50, 0.60, 0.45]) * (0.8 + front.mean()), 0, 1)
        width = float(np.ptp(outline.poly[:, 1])) * length
        pet_r = float(np.clip(width * rng.uniform(0.025, 0.045), 0.001, 0.0035))
        hole = None
        if rng.uniform() < spec.holes:
            k = int(rng.integers(len(outline.poly)))
            c2 = outline.centre + rng.uniform(0.5, 0.9) * (outline.poly[k] - outline.centre)
            hole = (c2, float(rng.uniform(0.08, 0.18)) * float(np.ptp(outline.poly[:, 1]) + 0.3) / 1.3)
        spots = []
        if rng.uniform() < spec.spots:
            inside = outline.poly[rng.integers(0, len(outline.poly), int(rng.integers(1, 5)))]
            for q in inside:
                c2 = outline.centre + rng.uniform(0.2, 0.85) * (q - outline.centre)
                spots.append((c2, float(rng.uniform(0.01, 0.035))))
        leaves.append(_Leaf(sheet=sheet, place=pl, label=j + 1, colour_front=front, hole=hole,
                            spots=spots,
                            colour_back=back, density=float(np.exp(rng.normal(0, 0.25))),
                            back_fraction=float(rng.uniform(0.1, 0.5)),
                            vein_phase=float(rng.uniform(0, 1)),
                            n_secondary=int(rng.integers(7, 13)), pet_radius=pet_r))
    return axes, leaves, habit


# ---- overlap construction and collision avoidance ------------------------------------------

def _min_dist(a: np.ndarray, tree: cKDTree, upper: float = 0.03) -> float:
    """Smallest distance from points ``a`` to ``tree``'s points, capped at ``upper`` (metres)."""
    lo, hi = tree.mins - upper, tree.maxes + upper
    if np.any(a.min(0) > hi) or np.any(a.max(0) < lo):
        return upper
    inside = np.all((a >= lo) & (a <= hi), axis=1)
    if not inside.any():
        return upper
    return float(min(upper, tree.query(a[inside], k=1, distance_upper_bound=upper)[0].min()))


def _place_pairs(leaves: list[_Leaf], axes, spec: PlantSpec, rng) -> list[tuple[int, int, int]]:
    """Turn some consecutive leaf pairs into touching/vertical/horizontal overlaps.

    Returns [(label_a, label_b, type)] with type 1 touching, 2 vertical, 3 horizontal.
    """
    if spec.overlap == "none" or len(leaves) < 2:
        return []
    types = {"touching": [1], "vertical": [2], "horizontal": [3], "all": [1, 2, 3]}[spec.overlap]
    n_pairs = max(len(types), len(leaves) // 5)
    # candidate pairs: leaves on the same axis, b the next one up
    order = sorted(range(len(leaves)), key=lambda i: (leaves[i].place.axis, leaves[i].place.t))
    cands = [(order[i], order[i + 1]) for i in range(len(order) - 1)
             if leaves[order[i]].place.axis == leaves[order[i + 1]].place.axis]
    rng.shuffle(cands)
    # fallbacks: next-but-one leaves on the same axis
    more = [(order[i], order[i + 2]) for i in range(len(order) - 2)
            if leaves[order[i]].place.axis == leaves[order[i + 2]].place.axis]
    rng.shuffle(more)
    cands += more
    out = []
    fixed: list[int] = []
    for a, b in cands:
        if len(out) >= n_pairs:
            break
        if a in fixed or b in fixed:
            continue
        ty = types[len(out) % len(types)]
        A, B = leaves[a], leaves[b]
        saved = dataclasses.replace(B.place)
        # B's blade: same size class as A so they can stack
        tree = cKDTree(A.world())
        pa, pb = A.place, B.place
        pb.pet_len = pa.pet_len * float(rng.uniform(0.9, 1.1))
        pb.el_pet = pa.el_pet
        pb.roll = pa.roll + float(rng.normal(0, 0.05))
        axis = axes[pa.axis]
        if ty == 1:    # touching: side by side, margins ~1 mm apart
            gap = float(rng.uniform(0.0005, 0.002))
            pb.t = pa.t
            pb.node = pa.node + np.array([0, 0, float(rng.uniform(0.0, 0.004))])
            pb.el_blade = pa.el_blade + float(rng.normal(0, 0.05))
            sign = 1.0 if rng.uniform() < 0.5 else -1.0

            def f(x):
                pb.az = pa.az + sign * x
                return _min_dist(B.world(), tree)
            lo, hi = 0.0, 2.0
        else:          # vertical / horizontal: B above A, lowered onto it
            gap = float(rng.uniform(0.002, 0.006)) if ty == 2 else float(rng.uniform(0.0015, 0.004))
            dz = float(rng.uniform(0.01, 0.03)) if ty == 2 else float(rng.uniform(0.0, 0.006))
            p, _, _ = axis.at(min(1.0, pa.t))
            pb.node = p + np.array([0, 0, dz])
            if ty == 2:
                pb.az = pa.az + float(rng.normal(0, 0.06))
            else:
                w = float(np.ptp(A.sheet.uv2d[:, 1])) * A.sheet.params.length
                dist = np.linalg.norm(A.to_world(A.sheet.local.mean(0)) - pa.node)
                pb.az = pa.az + (1 if rng.uniform() < 0.5 else -1) * float(
                    np.clip(rng.uniform(0.45, 0.75) * w / max(dist, 1e-3), 0.15, 0.9))
            base_el = pa.el_blade

            def f(x):
                pb.el_blade = base_el + x
                pb.el_pet = pa.el_pet + 0.5 * x
                return _min_dist(B.world(), tree)
            lo, hi = -0.2, 1.2
        # f is ~monotone increasing on [lo, hi]; find f(x) = gap
        if f(hi) < gap:
            hi = 2.5
        if f(lo) > gap:
            lo = -1.0 if ty != 1 else lo
        if f(lo) > gap:
            B.place = saved  # cannot bring the blades together from here: not a pair
            continue
        else:
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                if f(mid) > gap:
                    hi = mid
                else:
                    lo = mid
            f(hi)
        # B must not run into an earlier pair's blades (that would be an unplanned overlap)
        wa, wb = A.world(), B.world()
        if any(min(_min_dist(wb, cKDTree(leaves[k].world())), _min_dist(wa, cKDTree(leaves[k].world())))
               < 0.006 for k in fixed):
            B.place = saved
            continue
        fixed += [a, b]
        out.append((A.label, B.label, ty))
    return out


def _avoid_collisions(leaves: list[_Leaf], axes: list[Axis], pairs, rng, min_gap=0.006,
                      tries=16, passes=3):
    """Re-pose leaves closer than ``min_gap`` to another blade (built pairs excepted) or a stem.

    Leaves of built overlap pairs keep their pose; the others get new azimuth/elevations (the
    best of ``tries`` random re-poses is kept). Several passes, since moving one leaf can
    bring it close to a later one.
    """
    partner: dict[int, set] = {}
    for a, b, _ in pairs:
        partner.setdefault(a, set()).add(b)
        partner.setdefault(b, set()).add(a)
    fixed = set(partner)
    stem_pts = np.vstack([a.pts for a in axes])
    stem_r = np.concatenate([a.radius for a in axes])
    stem_tree = cKDTree(stem_pts)
    worlds = [lf.world() for lf in leaves]
    trees = [cKDTree(w[::3]) for w in worlds]

    def clearance(i, w):
        d = np.inf
        for k in range(len(leaves)):
            if k == i or leaves[k].label in partner.get(leaves[i].label, ()):
                continue
            d = min(d, _min_dist(w[::5], trees[k], upper=min_gap * 2))
        # blades must also clear the stems (but may start right at their own node)
        far = np.linalg.norm(w - leaves[i].place.node, axis=1) > 0.03
        if far.any():
            dd, ii = stem_tree.query(w[far][::3], k=1)
            d = min(d, float((dd - stem_r[ii]).min()))
        return d

    for _ in range(passes):
        moved = False
        for i, leaf in enumerate(leaves):
            if leaf.label in fixed or clearance(i, worlds[i]) >= min_gap:
                continue
            pl = leaf.place
            az0, eb0, ep0 = pl.az, pl.el_blade, pl.el_pet
            best = (clearance(i, worlds[i]), az0, eb0, ep0)
            for _ in range(tries):
                pl.az = az0 + rng.normal(0, 0.7)
                pl.el_blade = eb0 + rng.normal(0, 0.25)
                pl.el_pet = float(np.clip(ep0 + rng.normal(0, 0.15), -0.2, 1.45))
                d = clearance(i, leaf.world())
                if d > best[0]:
                    best = (d, pl.az, pl.el_blade, pl.el_pet)
                if d >= min_gap:
                    break
            _, pl.az, pl.el_blade, pl.el_pet = best
            worlds[i] = leaf.world()
            trees[i] = cKDTree(worlds[i][::3])
            moved = True
        if not moved:
            break


# ---------------------------------------------------------------------------------------------
# Gaussian sampling
# ---------------------------------------------------------------------------------------------

def _smooth_noise(p: np.ndarray, rng, n_waves=6, scale=1.0) -> np.ndarray:
    """Deterministic smooth noise in ~[-1, 1] at points p (N, D), wavelength ~ scale."""
    d = p.shape[1]
    k = rng.normal(0, 1, (n_waves, d)) * (2 * np.pi / scale)
    ph = rng.uniform(0, 2 * np.pi, n_waves)
    return (np.sin(p @ k.T + ph).sum(1)) / np.sqrt(n_waves / 2)


def _sample_leaf(leaf: _Leaf, n: int, rng, glossy: float, variegation: float = 0.0,
                 noise: float = 0.0006, fuzz_fraction: float = 0.02):
    """Gaussians on one blade, canonical frame: positions, scales (in-plane, in-plane, normal),
    rotation matrices (N, 3, 3) [columns = axes], RGB, opacities, SH-rest noise level and the
    samples' ``LeafSites`` (normal, outward direction, distance to the margin)."""
    sh = leaf.sheet
    Vw = leaf.world()
    F = sh.faces
    N = vertex_normals(Vw, F)
    e1, e2 = Vw[F[:, 1]] - Vw[F[:, 0]], Vw[F[:, 2]] - Vw[F[:, 0]]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    cen2 = sh.uv2d[F].mean(1)
    rad_c = sh.radial[F].mean(1)
    # uneven density: smooth blotches, sparser towards the margin
    dens = np.exp(0.55 * _smooth_noise(cen2, rng, 5, 0.5))
    dens *= 0.35 + 0.65 * np.clip((1.0 - rad_c) / 0.3, 0, 1) ** 0.7
    if leaf.hole is not None:  # an occluded / badly reconstructed patch: almost no Gaussians
        c2, r2 = leaf.hole
        dens *= np.where(np.linalg.norm(cen2 - c2, axis=1) < r2, 0.03, 1.0)
    w = area * dens
    fi = rng.choice(len(F), size=n, p=w / w.sum())
    r1, r2 = rng.uniform(size=n), rng.uniform(size=n)
    s1 = np.sqrt(r1)
    b = np.stack([1 - s1, s1 * (1 - r2), s1 * r2], 1)
    tri = F[fi]
    pos = np.einsum("nk,nkd->nd", b, Vw[tri])
    nrm = np.einsum("nk,nkd->nd", b, N[tri])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    xy = np.einsum("nk,nkd->nd", b, sh.uv2d[tri])
    rad = np.einsum("nk,nk->n", b, sh.radial[tri])
    # tangent along the midrib direction (x of the 2D frame) from the face Jacobian
    q = sh.uv2d[F]
    E2 = np.stack([q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]], 2)      # (F, 2, 2) columns
    E3 = np.stack([e1, e2], 2)                                     # (F, 3, 2)
    det = E2[:, 0, 0] * E2[:, 1, 1] - E2[:, 0, 1] * E2[:, 1, 0]
    det = np.where(np.abs(det) < 1e-14, 1e-14, det)
    inv_col0 = np.stack([E2[:, 1, 1], -E2[:, 1, 0]], 1) / det[:, None]  # first column of inv(E2)
    tx = np.einsum("fdk,fk->fd", E3, inv_col0)[fi]
    tx -= np.einsum("nd,nd->n", tx, nrm)[:, None] * nrm
    tn = np.linalg.norm(tx, axis=1, keepdims=True)
    tx = np.where(tn > 1e-12, tx / np.maximum(tn, 1e-12), np.cross(nrm, [0.0, 0.0, 1.0] + 0 * nrm))
    tx /= np.maximum(np.linalg.norm(tx, axis=1, keepdims=True), 1e-12)
    # front / back side, thickness, jitter
    back = rng.uniform(size=n) < leaf.back_fraction
    # off-surface noise as in real reconstructions: half the blade thickness to either side,
    # a per-leaf noise level (some leaves are reconstructed worse), a heavy tail, and "fuzz":
    # a few Gaussians floating a few mm above the front (the usual 3DGS haze over glossy sheets)
    thick = 0.0004 * float(np.exp(rng.normal(0, 0.2)))
    sigma = float(np.clip(noise * np.exp(rng.normal(0, 0.45)), 0.2 * noise, 3 * noise))
    off = np.where(back, -0.5, 0.5) * thick + rng.normal(0, sigma, n)
    heavy = rng.uniform(size=n) < 0.04
    off += heavy * rng.normal(0, 4 * sigma, n)
    fuzz = rng.uniform(size=n) < fuzz_fraction
    off += fuzz * np.abs(rng.normal(0, 0.004, n)) * np.where(back, -1, 1)
    pos = pos + off[:, None] * nrm
    # orientation: in-plane angle, parallel-veined leaves align with the midrib
    parallel = sh.outline.venation == "parallel"
    psi = rng.normal(0, 0.3, n) if parallel else rng.uniform(0, np.pi, n)
    bx = np.cross(nrm, tx)
    a1 = np.cos(psi)[:, None] * tx + np.sin(psi)[:, None] * bx
    a2 = -np.sin(psi)[:, None] * tx + np.cos(psi)[:, None] * bx
    R = np.stack([a1, a2, nrm], 2)
    total_area = float(area.sum())
    spacing = np.sqrt(2 * total_area / max(n, 1))
    local = np.sqrt(np.clip(dens[fi] / dens.mean(), 0.2, 5.0))
    s_1 = spacing * 0.7 * np.exp(rng.normal(0, 0.35, n)) / local
    # keep splats inside the outline: no in-plane scale beyond ~0.6x the distance to the margin
    # (measured along the polar ray), so blade silhouettes stay crisp as in real captures
    ray = np.linalg.norm(np.einsum("nk,nkd->nd", b, sh.uv2d[tri]) - sh.outline.centre, axis=1)
    d_edge = (1.0 - rad) / np.maximum(rad, 1e-3) * ray * sh.params.length
    s_1 = np.minimum(s_1, np.maximum(0.6 * d_edge, 0.2 * spacing))
    s_2 = s_1 * rng.uniform(0.3, 1.0, n) * (0.6 if parallel else 1.0)
    s_3 = s_1 * rng.uniform(0.02, 0.1, n)
    s_3 = np.where(fuzz, np.minimum(s_1 * rng.uniform(0.2, 0.6, n), 0.9 * s_2), s_3)
    scales = np.stack([s_1, s_2, s_3], 1)
    # colour
    veins = vein_field(sh.outline, xy, leaf.vein_phase, leaf.n_secondary)
    mott = 0.07 * _smooth_noise(xy, rng, 6, 0.35)
    front = leaf.colour_front[None, :] * (1 + mott[:, None])
    vein_f = np.clip(leaf.colour_front * 1.6 + np.array([0.08, 0.09, 0.02]), 0, 1)
    front = front + 0.7 * veins[:, None] * (vein_f - front)
    edge = np.clip((rad - 0.93) / 0.07, 0, 1)[:, None]
    front = front + 0.25 * edge * (np.array([0.45, 0.42, 0.12]) - front)
    if variegation > 0:  # streaks running out from the midrib
        streak = _smooth_noise(np.stack([xy[:, 0] * 0.6, np.abs(xy[:, 1]) * 3.0], 1), rng, 6, 0.5)
        v = np.clip((streak - (1.2 - 1.6 * variegation)) / 0.4, 0, 1)[:, None]
        front = front + 0.8 * v * (np.array([0.85, 0.8, 0.35]) - front)
    for c2, r2 in leaf.spots:
        d = np.linalg.norm(xy - c2, axis=1)
        w = np.clip(1.0 - d / r2, 0, 1)[:, None] ** 0.5
        front = front + 0.9 * w * (np.array([0.32, 0.22, 0.08]) - front)
    bk = leaf.colour_back[None, :] * (1 + 0.6 * mott[:, None])
    vein_b = np.clip(leaf.colour_back * 1.25 + 0.05, 0, 1)
    bk = bk + 0.8 * veins[:, None] * (vein_b - bk)
    col = np.where(back[:, None], bk, front)
    col = np.clip(col + rng.normal(0, 0.015, (n, 3)), 0.003, 0.997)
    opa = np.where(rng.uniform(size=n) < 0.85, rng.uniform(0.8, 0.999, n), rng.uniform(0.03, 0.7, n))
    opa = np.where(fuzz, rng.uniform(0.02, 0.3, n), opa)
    rest_sd = 0.01 + 0.05 * glossy * (~back)
    # where each sample sits (for capture realism): outward along the polar ray, in 3D
    inv_col1 = np.stack([-E2[:, 0, 1], E2[:, 0, 0]], 1) / det[:, None]
    out2 = np.einsum("nk,nkd->nd", b, sh.uv2d[tri]) - sh.outline.centre
    out2 /= np.maximum(np.linalg.norm(out2, axis=1, keepdims=True), 1e-12)
    J0 = np.einsum("fdk,fk->fd", E3, inv_col0)[fi]
    J1 = np.einsum("fdk,fk->fd", E3, inv_col1)[fi]
    outward = out2[:, :1] * J0 + out2[:, 1:] * J1
    outward -= np.einsum("nd,nd->n", outward, nrm)[:, None] * nrm
    outward /= np.maximum(np.linalg.norm(outward, axis=1, keepdims=True), 1e-12)
    sites = LeafSites(normal=nrm, outward=outward, to_margin=np.maximum(d_edge, 0.0))
    return pos, scales, R, col, opa, rest_sd, sites


def _tube_frames(t):
    ref = np.where(np.abs(t[:, 2:3]) < 0.9, np.array([[0, 0, 1.0]]), np.array([[1.0, 0, 0]]))
    e1 = np.cross(t, ref)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(t, e1)
    return e1, e2


def _sample_tube(axis: Axis, n: int, rng, colour, colour_end=None, jitter=0.0003):
    """Gaussians on a tube's surface, elongated along the centreline.

    colour : RGB at the start of the tube, blending to ``colour_end`` (if given) at its end.
    """
    if n <= 0:
        return None
    r_mid = 0.5 * (axis.radius[1:] + axis.radius[:-1])
    seg = np.diff(axis.s)
    w = seg * r_mid
    si = rng.choice(len(seg), size=n, p=w / w.sum())
    u = rng.uniform(size=n)
    p0, p1 = axis.pts[si], axis.pts[si + 1]
    c = p0 + u[:, None] * (p1 - p0)
    r = axis.radius[si] + u * (axis.radius[si + 1] - axis.radius[si])
    tan = (p1 - p0) / np.linalg.norm(p1 - p0, axis=1, keepdims=True)
    e1, e2 = _tube_frames(tan)
    ang = rng.uniform(0, 2 * np.pi, n)
    radial = np.cos(ang)[:, None] * e1 + np.sin(ang)[:, None] * e2
    around = np.cross(radial, tan)  # [tan, around, radial] right-handed
    pos = c + (r + rng.normal(0, jitter, n))[:, None] * radial
    area = 2 * np.pi * float(w.sum())
    spacing = np.sqrt(area / n)
    s_around = np.minimum(spacing * 0.6, r * 0.45) * np.exp(rng.normal(0, 0.3, n))
    s_along = s_around * rng.uniform(1.8, 4.0, n)
    s_rad = s_around * rng.uniform(0.05, 0.2, n)
    R = np.stack([tan, around, radial], 2)
    shade = 0.75 + 0.5 * np.clip(radial[:, 2], -0.5, 1.0)[:, None] * 0.4
    base = np.asarray(colour, float)[None, :]
    if colour_end is not None:
        along = ((axis.s[si] + u * seg[si]) / max(axis.length, 1e-12))[:, None]
        base = base + np.clip(along * 1.4, 0, 1) * (np.asarray(colour_end, float) - base)
    if axis.internode > 0:
        sa = axis.s[si] + u * seg[si]
        ring = np.abs(np.mod(sa / axis.internode + 0.5, 1.0) - 0.5) * axis.internode < 0.002
        base = np.where(ring[:, None], base * 0.6 + 0.05, base)
    col = np.clip(base * shade * np.exp(rng.normal(0, 0.07, (n, 1)))
                  + rng.normal(0, 0.015, (n, 3)), 0.003, 0.997)
    opa = np.where(rng.uniform(size=n) < 0.9, rng.uniform(0.85, 0.999, n), rng.uniform(0.1, 0.7, n))
    return pos, np.stack([s_along, s_around, s_rad], 1), R, col, opa


def tube_surface_samples(axes: list[Axis], n: int, rng) -> np.ndarray:
    """(n, 3) points uniformly by area on the exact surfaces of the tubes (canonical frame)."""
    segs = []
    for a in axes:
        r_mid = 0.5 * (a.radius[1:] + a.radius[:-1])
        segs.append((a, np.diff(a.s) * r_mid))
    w = np.concatenate([x for _, x in segs])
    ai = np.concatenate([np.full(len(x), i) for i, (_, x) in enumerate(segs)])
    si = np.concatenate([np.arange(len(x)) for _, x in segs])
    pick = rng.choice(len(w), size=n, p=w / w.sum())
    u = rng.uniform(size=n)
    ang = rng.uniform(0, 2 * np.pi, n)
    out = np.zeros((n, 3))
    for i, (a, _) in enumerate(segs):
        m = ai[pick] == i
        if not m.any():
            continue
        s_ = si[pick[m]]
        p0, p1 = a.pts[s_], a.pts[s_ + 1]
        c = p0 + u[m, None] * (p1 - p0)
        r = a.radius[s_] + u[m] * (a.radius[s_ + 1] - a.radius[s_])
        tan = (p1 - p0) / np.linalg.norm(p1 - p0, axis=1, keepdims=True)
        e1, e2 = _tube_frames(tan)
        out[m] = c + r[:, None] * (np.cos(ang[m])[:, None] * e1 + np.sin(ang[m])[:, None] * e2)
    return out


def _random_rotation(rng) -> np.ndarray:
    q = rng.normal(0, 1, 4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


# ---------------------------------------------------------------------------------------------
# the public entry point
# ---------------------------------------------------------------------------------------------

def _structure(spec: PlantSpec, seed: int):
    """The plant's geometry before any Gaussian is drawn: tubes (stem, branches and, last, one
    petiole per leaf), placed leaves, habit, overlap pairs, and the random streams ``make_plant``
    goes on with (Gaussian sampling, global frame, surroundings)."""
    # independent streams: structure, overlap/collision posing, Gaussian sampling, global frame
    # (so that changing how Gaussians are sampled never changes the plant's geometry)
    ss = np.random.SeedSequence([int(seed), 0x1EAF])
    rng_build, rng_pose, rng, rng_frame, rng_scene = (np.random.default_rng(c) for c in ss.spawn(5))
    axes, leaves, habit = _build(spec, rng_build)
    pairs = _place_pairs(leaves, axes, spec, rng_pose)
    _avoid_collisions(leaves, axes, pairs, rng_pose)

    # petioles: cubic Bezier from the node (on the stem surface) to the blade base,
    # leaving along (az, el_pet) and arriving along the blade's midrib direction
    for leaf in leaves:
        pl = leaf.place
        ax = axes[pl.axis]
        _, _, r_node = ax.at(pl.t)
        d0 = _dir(pl.az, pl.el_pet)
        p0 = pl.node + d0 * r_node * 0.8
        p3 = pl.blade_base()
        x_axis = pl.frame()[:, 0]
        ln = np.linalg.norm(p3 - p0)
        pts = _bezier(p0, p0 + d0 * ln * 0.4, p3 - x_axis * ln * 0.3, p3)
        rr = leaf.pet_radius * np.linspace(1.25, 0.9, len(pts))
        axes.append(Axis(pts, rr, "petiole"))
        axes[-1].leaf = leaf.label

    return axes, leaves, habit, pairs, (rng, rng_frame, rng_scene)


STEM_SAMPLES = 20000


def stem_samples_rng(seed: int) -> np.random.Generator:
    """The random stream ``GroundTruth.stem_samples`` are drawn with (``STEM_SAMPLES`` points by
    :func:`tube_surface_samples` on :func:`plant_tubes`)."""
    return np.random.default_rng([int(seed), 0x57E3])


def plant_tubes(spec: PlantSpec, seed: int) -> list[Axis]:
    """The tubes of the plant ``make_plant(spec, seed)`` builds (stem, branches, petioles:
    centrelines and radii, in the frame the plant is built in: ``make_plant`` then rescales it to
    a canonical height and maps it to the input frame), the exact surface its ``stem_samples``
    are drawn on: open tubes, no end caps.
    A petiole starts inside its parent, 0.8 of the parent's radius from its axis."""
    return _structure(spec, seed)[0]


def make_plant(spec: PlantSpec, seed: int) -> tuple[GaussianCloud, GroundTruth]:
    """Generate one plant: a GaussianCloud (input frame, shuffled file order) and its GroundTruth.

    Deterministic: the same (spec, seed) gives bit-identical arrays.
    """
    axes, leaves, habit, pairs, (rng, rng_frame, rng_scene) = _structure(spec, seed)
    capture = spec.realism == "capture"
    leaf_sites: list[LeafSites] = []
    L = len(leaves)
    n_total = int(spec.gaussians)
    n_float = int(round(spec.floaters * n_total))
    leaf_area = np.array([0.5 * np.linalg.norm(np.cross(
        lf.sheet.local[lf.sheet.faces[:, 1]] - lf.sheet.local[lf.sheet.faces[:, 0]],
        lf.sheet.local[lf.sheet.faces[:, 2]] - lf.sheet.local[lf.sheet.faces[:, 0]]), axis=1).sum()
        for lf in leaves])
    tube_area = np.array([2 * np.pi * float((np.diff(a.s) * 0.5 * (a.radius[1:] + a.radius[:-1])).sum())
                          for a in axes])
    # stems get ~0.7x the leaf density per side (leaves carry two sides), thin petioles more
    # (3DGS over-densifies thin, high-contrast structures)
    wl = leaf_area * 2 * np.array([lf.density for lf in leaves])
    wt = tube_area * np.array([1.3 if a.kind == "petiole" else 0.7 for a in axes])
    n_plant = n_total - n_float
    frac_t = float(np.clip(wt.sum() / (wt.sum() + wl.sum()), 0.04, 0.3))
    n_t = int(round(n_plant * frac_t))
    n_l = n_plant - n_t
    cnt_l = np.floor(n_l * wl / wl.sum()).astype(int)
    cnt_l[np.argmax(cnt_l)] += n_l - cnt_l.sum()
    cnt_t = np.floor(n_t * wt / wt.sum()).astype(int)
    cnt_t[0] += n_t - cnt_t.sum()

    parts_pos, parts_sc, parts_R, parts_col, parts_op, parts_rest, parts_lab = [], [], [], [], [], [], []
    parts_pet = []
    stem_col = np.array(spec.palette if spec.palette is not None else _KIND_DEFAULTS[spec.kind][3])
    stem_col = np.clip(0.6 * stem_col + 0.4 * np.array([0.35, 0.3, 0.15]), 0, 1)
    woody = np.array([0.30, 0.22, 0.13]) * float(np.exp(rng.normal(0, 0.1)))
    for ai, (a, c) in enumerate(zip(axes, cnt_t)):
        if a.kind == "stem":
            # the main stem lignifies from the base; branches and shoots stay greener
            c0, c1 = (woody if ai == 0 and habit != "rosette" else stem_col), stem_col
        else:
            lf = leaves[a.leaf - 1]
            c0 = c1 = np.clip(0.7 * lf.colour_front + 0.3 * np.array([0.45, 0.5, 0.2]), 0, 1)
        out = _sample_tube(a, int(c), rng, c0, c1)
        if out is None:
            continue
        pos, sc, R, col_, op = out
        parts_pos.append(pos); parts_sc.append(sc); parts_R.append(R); parts_col.append(col_)
        parts_op.append(op); parts_rest.append(np.full(len(pos), 0.01)); parts_lab.append(np.zeros(len(pos), np.int32))
        parts_pet.append(np.full(len(pos), getattr(a, "leaf", 0), np.int32))
    for lf, c in zip(leaves, cnt_l):
        noise = spec.surface_noise * (LAYER_NOISE if capture else 1.0)
        pos, sc, R, col, op, rest, site = _sample_leaf(lf, int(c), rng, spec.glossy,
                                                         spec.variegation, noise, spec.fuzz)
        leaf_sites.append(site)
        parts_pos.append(pos); parts_sc.append(sc); parts_R.append(R); parts_col.append(col)
        parts_op.append(op); parts_rest.append(rest); parts_lab.append(np.full(len(pos), lf.label, np.int32))
        parts_pet.append(np.zeros(len(pos), np.int32))
    plant_pts = np.vstack(parts_pos)
    # floaters: half scattered in the plant's box, half in small clumps near it
    if n_float:
        lo, hi = plant_pts.min(0), plant_pts.max(0)
        ctr, ext = 0.5 * (lo + hi), 0.5 * (hi - lo)
        n1 = n_float // 2
        p1 = ctr + rng.uniform(-1.2, 1.2, (n1, 3)) * ext
        n2 = n_float - n1
        clumps = ctr + rng.uniform(-1.1, 1.1, (max(1, n2 // 12), 3)) * ext
        p2 = clumps[rng.integers(0, len(clumps), n2)] + rng.normal(0, 0.01, (n2, 3))
        pf = np.vstack([p1, p2])
        # keep floaters within the plant's height range (reflect, don't pile them on a plane)
        zlo, zhi = 0.01 * hi[2], 0.97 * hi[2]
        z = np.abs(pf[:, 2] - zlo)
        z = np.mod(z, 2 * (zhi - zlo))
        pf[:, 2] = zlo + np.where(z > zhi - zlo, 2 * (zhi - zlo) - z, z)
        scf = np.exp(rng.normal(np.log(0.004), 0.6, (n_float, 3)))
        parts_pos.append(pf); parts_sc.append(scf)
        parts_R.append(np.stack([_random_rotation(rng) for _ in range(n_float)]))
        parts_col.append(np.clip(rng.uniform(0.2, 0.8, (n_float, 1)) + rng.normal(0, 0.05, (n_float, 3)), 0, 1))
        parts_op.append(rng.uniform(0.02, 0.6, n_float)); parts_rest.append(np.full(n_float, 0.05))
        parts_lab.append(np.full(n_float, -1, np.int32))
        parts_pet.append(np.zeros(n_float, np.int32))
    pos = np.vstack(parts_pos)
    scales = np.vstack(parts_sc)
    R = np.concatenate(parts_R)
    col = np.vstack(parts_col)
    opa = np.concatenate(parts_op)
    rest_sd = np.concatenate(parts_rest)
    labels = np.concatenate(parts_lab)
    petiole_of = np.concatenate(parts_pet)

    # keep canonical plant heights within 0.3-1.2 m (a uniform rescale, ~1 for most specs)
    hz = pos[labels >= 0, 2]
    h_c = float(hz.max() - min(hz.min(), 0.0))
    k = float(np.clip(h_c, 0.3, 1.2) / h_c)
    pos, scales = pos * k, scales * k
    if capture:  # trained-capture statistics (own random stream: the ideal draws are unchanged)
        from samples.capture import capture_rng, realise_plant

        rng_capture = capture_rng(seed)
        sites = LeafSites(*(np.concatenate([getattr(x, f) for x in leaf_sites]) * (k if f == "to_margin" else 1)
                            for f in ("normal", "outward", "to_margin")))
        pos, scales, R, opa = realise_plant(pos, scales, R, opa, labels, sites, h_c * k, rng_capture)
    scene_info = None
    scene_class = None
    if spec.scene:  # capture-like surroundings (own random stream: the plant is unchanged)
        if spec.scene == "pot":
            from samples.capture import make_pot_scene

            s_pos, s_sc, s_R, s_col, s_op, s_cls, scene_info = make_pot_scene(
                h_c * k, int(spec.gaussians), rng_scene, spec.pot)
        else:
            from samples.scene import make_scene

            s_pos, s_sc, s_R, s_col, s_op, s_cls, scene_info = make_scene(
                pos[labels >= 0], h_c * k, int(spec.gaussians), rng_scene)
        if capture:
            from samples.capture import realise_scene

            s_sc, s_R, s_op = realise_scene(s_sc, s_R, s_op, s_cls, rng_capture)
        scene_class = np.concatenate([np.where(labels >= 0, 0, 5), s_cls]).astype(np.int8)
        pos, scales = np.vstack([pos, s_pos]), np.vstack([scales, s_sc])
        R = np.concatenate([R, s_R])
        col, opa = np.vstack([col, s_col]), np.concatenate([opa, s_op])
        rest_sd = np.concatenate([rest_sd, np.full(len(s_pos), 0.01)])
        labels = np.concatenate([labels, np.full(len(s_pos), -2, np.int32)])
        petiole_of = np.concatenate([petiole_of, np.zeros(len(s_pos), np.int32)])

    # global similarity: canonical -> input (an SfM frame)
    if spec.global_frame:
        Rg = _random_rotation(rng_frame)
        sg = float(np.exp(rng_frame.uniform(np.log(0.3), np.log(4.0))))
        tg = rng_frame.normal(0, 1.5, 3)
    else:
        Rg, sg, tg = np.eye(3), 1.0, np.zeros(3)
    M = np.eye(4)
    M[:3, :3] = sg * Rg
    M[:3, 3] = tg
    pos_in = pos @ (sg * Rg).T + tg
    R_in = np.einsum("ij,njk->nik", Rg, R)
    quats = matrix_to_quat(R_in)
    # trainers store unnormalised quaternions of either sign
    quats *= (np.exp(rng.normal(0, 0.4, len(quats))) * np.where(rng.uniform(size=len(quats)) < 0.5, -1, 1))[:, None]
    scales_in = scales * sg

    deg = int(spec.sh_degree)
    C = (deg + 1) ** 2
    sh = np.zeros((len(pos), C, 3))
    sh[:, 0, :] = (col - 0.5) / SH_C0
    if C > 1:
        sh[:, 1:, :] = rng.normal(0, 1, (len(pos), C - 1, 3)) * rest_sd[:, None, None]

    perm = rng.permutation(len(pos))
    cloud = GaussianCloud.from_activated(pos_in[perm], scales_in[perm], quats[perm], opa[perm],
                                         sh=sh[perm])
    cloud.quats = np.ascontiguousarray(quats[perm], np.float32)
    labels = labels[perm]
    petiole_of = petiole_of[perm]
    if scene_class is not None:
        scene_class = scene_class[perm]

    # ---- ground truth (input frame)
    def to_in(p):  # built (unscaled) canonical -> input
        return (k * np.asarray(p, np.float64)) @ (sg * Rg).T + tg
    root_c = np.zeros(3)
    root = to_in(root_c[None])[0]
    up = Rg @ np.array([0, 0, 1.0])
    stem_idx = np.flatnonzero(labels == 0)
    means64 = cloud.means.astype(np.float64)
    root_index = int(stem_idx[np.argmin(np.linalg.norm(means64[stem_idx] - root, axis=1))])
    h = (means64[labels >= 0] - root) @ up
    height = float(h.max() - min(h.min(), 0.0))
    verts, faces, vid = [], [], []
    off = 0
    for lf in leaves:
        w = lf.world()
        verts.append(to_in(w)); faces.append(lf.sheet.faces + off); vid.append(np.full(len(w), lf.label))
        off += len(w)
    info = [dict(label=lf.label, shape=lf.sheet.outline.shape, length_m=round(lf.sheet.params.length, 5),
                 axis=lf.place.axis, petiole_m=round(lf.place.pet_len, 5),
                 petiole_radius_m=round(lf.pet_radius, 5),
                 blade_width_m=round(float(np.ptp(lf.sheet.uv2d[:, 1])) * lf.sheet.params.length, 5))
            for lf in leaves]
    gt = GroundTruth(
        labels=labels.astype(np.int32), petiole_of=petiole_of.astype(np.int32), root=root,
        root_index=root_index, up=up, height=height,
        leaf_vertices=np.vstack(verts).astype(np.float32),
        leaf_faces=np.vstack(faces).astype(np.int32),
        leaf_vertex_ids=np.concatenate(vid).astype(np.int32),
        leaf_apex=to_in(np.array([lf.to_world(lf.sheet.apex) for lf in leaves])),
        leaf_base=to_in(np.array([lf.place.blade_base() for lf in leaves])),
        leaf_node=to_in(np.array([lf.place.node for lf in leaves])),
        overlap_pairs=np.array([(a, b) for a, b, _ in pairs], np.int32).reshape(-1, 2),
        overlap_types=np.array([t for _, _, t in pairs], np.int32),
        overlap_gaps=np.array([_min_dist(leaves[b - 1].world(), cKDTree(leaves[a - 1].world())) * sg * k
                               for a, b, _ in pairs], np.float64),
        canonical_to_input=M,
        stem_samples=to_in(tube_surface_samples(axes, STEM_SAMPLES, stem_samples_rng(seed))),
        spec=json.dumps({"spec": spec.to_dict(), "seed": int(seed), "habit": habit,
                         "canonical_height_m": height / sg, "leaves": info,
                         **({"scene": scene_info} if scene_info is not None else {})}),
        scene_class=scene_class,
    )
    return cloud, gt


# ---------------------------------------------------------------------------------------------
# presets and the benchmark suite
# ---------------------------------------------------------------------------------------------

def preset(name: str, **overrides) -> PlantSpec:
    """PlantSpec of a species-like preset (see PRESETS), with field overrides."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose from {sorted(PRESETS)}")
    return PlantSpec(**{**PRESETS[name], **overrides})


def benchmark_suite(gaussians: int = 100_000) -> list[tuple[str, PlantSpec, int]]:
    """The plants every benchmark runs on: [(name, spec, seed)].

    Mixes the paper's dataset classes (elliptic x6, multi-lobed, long-thin; 5-27 leaves) with
    plants it does not have (cordate, maple-like serrated, mixed shapes) and hard plants
    (``spec.hard``: touching, vertically and horizontally overlapping leaves).
    """
    g = int(gaussians)
    return [
        ("rubber_tree", preset("rubber_tree", gaussians=g), 1),
        ("green_pepper", preset("green_pepper", gaussians=g), 2),
        ("golden_pothos", preset("golden_pothos", gaussians=g), 3),
        ("black_pearl_pepper", preset("black_pearl_pepper", gaussians=g), 4),
        ("ruby_leaf", preset("ruby_leaf", gaussians=g), 5),
        ("white_flag_bush", preset("white_flag_bush", gaussians=g), 6),
        ("cotton_rose", preset("cotton_rose", gaussians=g), 7),
        ("lucky_bamboo", preset("lucky_bamboo", gaussians=g), 8),
        ("maple_seedling", preset("maple_seedling", gaussians=g), 9),
        ("mixed_shrub", PlantSpec(kind="mixed", leaves=16, gaussians=g), 10),
        ("hard_touching", PlantSpec(kind="elliptic", leaves=12, overlap="touching", gaussians=g), 11),
        ("hard_vertical", PlantSpec(kind="elliptic", leaves=10, overlap="vertical", gaussians=g), 12),
        ("hard_horizontal", PlantSpec(kind="lobed", leaves=10, overlap="horizontal", gaussians=g), 13),
        ("hard_all_thin", PlantSpec(kind="thin", leaves=15, overlap="all", gaussians=g), 14),
    ]


def capture_suite(gaussians: int = 60_000) -> list[tuple[str, PlantSpec, int]]:
    """Capture-like plants (``scene=True``: pot, soil, table, clutter, wall) for the isolation
    benchmark: [(name, spec, seed)]. ``gaussians`` counts the plant; the scene adds as many."""
    g = int(gaussians)
    return [
        ("capture_rubber_tree", preset("rubber_tree", gaussians=g, scene=True), 21),
        ("capture_green_pepper", preset("green_pepper", gaussians=g, scene=True), 22),
        ("capture_golden_pothos", preset("golden_pothos", gaussians=g, scene=True), 23),
        ("capture_ruby_leaf", preset("ruby_leaf", gaussians=g, scene=True), 24),
        ("capture_cotton_rose", preset("cotton_rose", gaussians=g, scene=True), 25),
        ("capture_lucky_bamboo", preset("lucky_bamboo", gaussians=g, scene=True), 26),
        *((n, s, sd) for n, (s, sd) in capture_realism_plants(int(0.6 * g)).items()),
    ]


def capture_realism_plants(gaussians: int = 36_000) -> dict[str, tuple[PlantSpec, int]]:
    """Plants with capture realism (``realism="capture"``: trained-3DGS opacities and shapes,
    layered leaves, edge fuzz, a pot with soil and no other surroundings): name -> (spec, seed).
    ``gaussians`` counts the plant; the pot and soil add about 0.7x that (36k: ~61k in all)."""
    g = int(gaussians)
    return {
        "rubber_tree_capture": (preset("rubber_tree", gaussians=g, realism="capture", pot="ceramic"), 31),
        "green_pepper_capture": (preset("green_pepper", gaussians=g, realism="capture",
                                        pot="terracotta"), 32),
        "golden_pothos_capture": (preset("golden_pothos", gaussians=g // 2, realism="capture",
                                         pot="terracotta"), 33),
    }


#: The sample plants of the demo and the tests: name -> (spec, seed). Not in git: ``make``
#: generates them at set-up (``python -m samples.generate --committed --out samples/plants``;
#: ``samples.ensure_plants()`` makes the missing ones).
def committed_plants() -> dict[str, tuple[PlantSpec, int]]:
    return {
        "rubber_tree": (preset("rubber_tree", gaussians=60_000, sh_degree=0), 1),
        "cotton_rose": (preset("cotton_rose", gaussians=60_000, sh_degree=0), 7),
        "lucky_bamboo": (preset("lucky_bamboo", gaussians=45_000, sh_degree=1), 8),
        "overlap": (PlantSpec(kind="elliptic", leaves=10, overlap="all", gaussians=60_000,
                              sh_degree=0, leaf_length=0.14, height=0.55), 12),
        "pothos_sh3": (preset("golden_pothos", gaussians=15_000, sh_degree=3), 3),
    }


# ---------------------------------------------------------------------------------------------
# CLI
# ---------------------------------------------------------------------------------------------

def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m samples.generate",
        description="Generate procedural 3DGS plants (INRIA PLY) with ground truth (NAME.gt.npz).")
    p.add_argument("--preset", choices=sorted(PRESETS), help="species-like preset (other options override it)")
    p.add_argument("--kind", choices=KINDS, help="leaf family (default elliptic)")
    p.add_argument("--leaves", type=int, help="number of leaves (default 14)")
    p.add_argument("--gaussians", type=int, help="number of Gaussians (default 100000)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--overlap", choices=OVERLAPS, help="build touching / overlapping leaf pairs")
    p.add_argument("--sh-degree", type=int, choices=range(4), help="SH degree 0..3 (default 0)")
    p.add_argument("--shape", choices=sorted(SHAPES), help="force one outline preset")
    p.add_argument("--serration", type=float, help="margin tooth depth in blade lengths (e.g. 0.02)")
    p.add_argument("--habit", choices=HABITS)
    p.add_argument("--height", type=float, help="approximate plant height, metres")
    p.add_argument("--floaters", type=float, help="fraction of floater Gaussians (default 0.003)")
    p.add_argument("--holes", type=float, help="fraction of leaves with a sparse patch (default 0.15)")
    p.add_argument("--no-global-frame", action="store_true", help="write the canonical frame (no random similarity)")
    p.add_argument("--scene", action="store_true",
                   help="capture-like: keep a pot, soil, a table, clutter and a back wall (label -2; "
                        "their classes in gt.scene_class); with --suite: capture_suite()")
    p.add_argument("--realism", choices=REALISMS,
                   help="ideal (default: clean opaque discs) | capture: the statistics of a trained "
                        "3DGS capture (faint opacities, needles, layered leaves, edge fuzz, more "
                        "floaters, a pot with soil; samples.capture)")
    p.add_argument("--pot", choices=POT_KINDS, help="pot of --scene / capture realism (default: from the seed)")
    p.add_argument("--bare", action="store_true", help="with --realism capture: no pot and soil")
    p.add_argument("--out", default=".", help="output directory")
    p.add_argument("--name", help="file stem (default: preset or kind + seed)")
    p.add_argument("--suite", action="store_true", help="write every benchmark_suite() plant")
    p.add_argument("--committed", action="store_true", help="regenerate the committed samples/plants")
    p.add_argument("--list", action="store_true", help="list presets, outline shapes and the benchmark suite")
    p.add_argument("-q", "--quiet", action="store_true")
    return p


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO, format="%(message)s")
    jobs: list[tuple[str, PlantSpec, int]] = []
    if args.list:
        print("presets:", ", ".join(sorted(PRESETS)))
        print("shapes: ", ", ".join(sorted(SHAPES)))
        print("benchmark suite (name, kind, leaves, overlap, seed):")
        for name, spec, seed in benchmark_suite():
            print(f"  {name:20s} {spec.kind:9s} {spec.leaves:3d}  {spec.overlap:10s} seed {seed}"
                  + ("  [hard]" if spec.hard else ""))
        return 0
    if args.suite:
        jobs = (capture_suite if args.scene else benchmark_suite)(args.gaussians or 100_000)
    elif args.committed:
        jobs = [(n, s, sd) for n, (s, sd) in committed_plants().items()]
    else:
        over = {k: v for k, v in dict(
            kind=args.kind, leaves=args.leaves, gaussians=args.gaussians, overlap=args.overlap,
            sh_degree=args.sh_degree, shape=args.shape, serration=args.serration,
            habit=args.habit, height=args.height, floaters=args.floaters,
            holes=args.holes).items() if v is not None}
        if args.no_global_frame:
            over["global_frame"] = False
        if args.scene:
            over["scene"] = True
        elif args.bare:
            over["scene"] = False
        if args.realism:
            over["realism"] = args.realism
        if args.pot:
            over["pot"] = args.pot
        try:
            spec = preset(args.preset, **over) if args.preset else PlantSpec(**over)
        except (ValueError, TypeError) as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        name = args.name or f"{args.preset or spec.kind}_{args.seed}"
        jobs = [(name, spec, args.seed)]
    for name, spec, seed in jobs:
        t0 = time.perf_counter()
        cloud, gt = make_plant(spec, seed)
        ply, gtp = save_plant(cloud, gt, args.out, name)
        log.info("%s: %d Gaussians, %d leaves, height %.3g (input units), %.1f s -> %s, %s",
                 name, len(cloud), gt.n_leaves, gt.height, time.perf_counter() - t0, ply, gtp)
    return 0


if __name__ == "__main__":
    sys.exit(main())
