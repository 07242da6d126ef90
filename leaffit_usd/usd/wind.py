"""Wind data of a plant, from what the asset already holds: every leaf instance sits at its
petiole, has a base-to-apex axis, and hangs on the stem skeleton.

Per leaf instance (PointInstancer primvars, :mod:`leaffit_usd.usd.writer`):

* **pivot** (3,), asset frame: the petiole base, the leaf's own MLS field evaluated at the
  template's base (the template local frame's origin: ``geometry.pca.leaf_frame`` puts the base
  there);
* **axis** (3,) unit, asset frame: from the pivot to the leaf's MLS image of the template's apex
  (its vertex farthest along the local x axis, which runs base -> apex);
* **node** int: the stem skeleton node it hangs from (the node nearest the pivot);
* **phase** float in [0, 1): a hash of the leaf's segmentation label (the same leaf, the same
  phase, in every export).

Per vertex (baked leaves, glTF, the stem; the common vertex-colour convention R = leaf flutter,
G = branch bend, B = phase):

* **flutter**: 0 at the leaf's base growing to 1 at its apex (template x / apex x, clipped);
* **bend**: the distance along the stem skeleton from the root to the node (stem vertex: its
  nearest node; leaf vertex: its leaf's node), over the largest such distance;
* **phase**: the leaf's (0 on the stem).

The skeleton (``skeleton_points`` (S, 3) asset frame, the end of each stem segment;
``skeleton_parents`` (S,) int, -1 at the root) comes from the stem's swept-tube segments.

The wind motion itself (:func:`wind_angles`, used by the CPU evaluator and transcribed in the
GLSL deformer): leaf j turns about its axis through its pivot by
``strength * sin(2 pi (frequency * time + phase_j))`` radians. Affine MLS is linear in the
targets and its weights sum to 1 at every point, so turning the K targets turns the evaluated
leaf rigidly: no extra storage, every leaf keeps its own shape.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leaffit_usd.fit.mls import mls_weights
from leaffit_usd.geometry.quaternion import quat_to_matrix


@dataclass(frozen=True)
class WindData:
    """See the module docstring. pivots, axes : (L, 3) float32, asset frame; nodes : (L,) int32;
    phases : (L,) float32; leaf_bend : (L,) float32; flutter : (V,) float32 per template vertex;
    stem_bend : (P,) float32 per stem vertex; pivots_local, axes_local : (L, 3) float64, each
    instance's local frame (before its transform; what the deformer rotates about)."""

    pivots: np.ndarray
    axes: np.ndarray
    nodes: np.ndarray
    phases: np.ndarray
    leaf_bend: np.ndarray
    flutter: np.ndarray
    stem_bend: np.ndarray
    pivots_local: np.ndarray
    axes_local: np.ndarray


def leaf_phases(labels: np.ndarray) -> np.ndarray:
    """(L,) float32 in [0, 1): an integer hash (splitmix32's finaliser) of each label."""
    x = np.asarray(labels, np.int64).astype(np.uint32)
    with np.errstate(over="ignore"):
        x = (x + np.uint32(0x9E3779B9)).astype(np.uint32)
        x = ((x ^ (x >> np.uint32(16))) * np.uint32(0x85EBCA6B)).astype(np.uint32)
        x = ((x ^ (x >> np.uint32(13))) * np.uint32(0xC2B2AE35)).astype(np.uint32)
        x = (x ^ (x >> np.uint32(16))).astype(np.uint32)
    return (x.astype(np.float64) / 2.0 ** 32).astype(np.float32)


def template_flutter(points: np.ndarray) -> np.ndarray:
    """(V,) float32: 0 at the template's base (its local origin) to 1 at its apex (largest x)."""
    x = np.asarray(points, np.float64)[:, 0] if len(points) else np.zeros(0)
    top = float(x.max()) if len(x) else 0.0
    return np.clip(x / top, 0.0, 1.0).astype(np.float32) if top > 0 else np.zeros(len(x), np.float32)


def skeleton_from_segments(starts: np.ndarray, ends: np.ndarray, parent: np.ndarray):
    """The stem skeleton of swept-tube segments (E, 3) with their parents (E,) (-1 at the root):
    (points (E + 1, 3), parents (E + 1,) int32): node 0 is the root (the first root segment's
    start), node i + 1 the end of segment i, hanging from its parent segment's end node."""
    starts, ends = np.asarray(starts, np.float64).reshape(-1, 3), np.asarray(ends, np.float64).reshape(-1, 3)
    if not len(ends):
        return np.zeros((0, 3)), np.zeros(0, np.int32)
    par = np.asarray(parent, np.int64)
    roots = np.flatnonzero(par < 0)
    root = starts[roots[0]] if len(roots) else starts[0]
    return np.vstack([root, ends]), np.r_[-1, np.where(par < 0, 0, par + 1)].astype(np.int32)


def skeleton_distances(points: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """(S,) float64 distance along the skeleton from its root (the node with parent -1) to each
    node (S, 3); parents (S,) int."""
    p = np.asarray(points, np.float64)
    par = np.asarray(parents, np.int64)
    d = np.full(len(p), np.nan)
    for i in range(len(p)):
        chain, j = [], i
        while j >= 0 and np.isnan(d[j]) and len(chain) <= len(p):
            chain.append(j)
            j = par[j]
        base = 0.0 if j < 0 else d[j]
        for k in reversed(chain):   # from the known node down to i
            pk = par[k]
            base = base + (np.linalg.norm(p[k] - p[pk]) if pk >= 0 else 0.0)
            d[k] = base
    return d


def wind_data(asset) -> WindData:
    """The wind data of a ``PlantAsset`` (module docstring)."""
    L = asset.n_leaves
    tp = np.asarray(asset.template_points, np.float64)
    apex = tp[int(np.argmax(tp[:, 0]))] if len(tp) else np.zeros(3)
    if L:
        A = mls_weights(np.asarray(asset.template_controls, np.float64), np.stack([np.zeros(3), apex]),
                        float(asset.sigma), float(asset.reg))               # (2, K)
        ends = np.einsum("pk,lkc->lpc", A, np.asarray(asset.targets, np.float64))
        piv_l, tip_l = ends[:, 0], ends[:, 1]
    else:
        piv_l = tip_l = np.zeros((0, 3))
    ax_l = tip_l - piv_l
    ax_l /= np.maximum(np.linalg.norm(ax_l, axis=1, keepdims=True), 1e-30)
    q = np.asarray(asset.orientations, np.float64).reshape(-1, 4)
    R = quat_to_matrix(q / np.maximum(np.linalg.norm(q, axis=1, keepdims=True), 1e-30)) if L else np.zeros((0, 3, 3))
    s = np.asarray(asset.scales, np.float64).reshape(-1, 3)
    pivots = np.asarray(asset.positions, np.float64) + np.einsum("lij,lj->li", R, s * piv_l)
    axes = np.einsum("lij,lj->li", R, s * ax_l)
    axes /= np.maximum(np.linalg.norm(axes, axis=1, keepdims=True), 1e-30)
    sk = getattr(asset, "skeleton_points", None)
    sp = np.zeros((0, 3)) if sk is None else np.asarray(sk, np.float64)
    stem = np.asarray(asset.stem_points, np.float64)
    nodes = np.zeros(L, np.int32)
    leaf_bend = np.zeros(L, np.float32)
    stem_bend = np.zeros(len(stem), np.float32)
    if len(sp):
        from scipy.spatial import cKDTree

        d = skeleton_distances(sp, asset.skeleton_parents)
        scale = float(d.max()) if d.max() > 0 else 1.0
        tree = cKDTree(sp)
        if L:
            nodes = tree.query(pivots, k=1)[1].astype(np.int32)
            leaf_bend = (d[nodes] / scale).astype(np.float32)
        if len(stem):
            stem_bend = (d[tree.query(stem, k=1)[1]] / scale).astype(np.float32)
    return WindData(pivots=pivots.astype(np.float32), axes=axes.astype(np.float32), nodes=nodes,
                    phases=leaf_phases(asset.leaf_labels), leaf_bend=leaf_bend,
                    flutter=template_flutter(tp), stem_bend=stem_bend, pivots_local=piv_l,
                    axes_local=ax_l)


@dataclass(frozen=True)
class WindParams:
    """A moment of wind: time (seconds), strength (radians: the largest turn of a leaf about its
    axis), frequency (Hz)."""

    time: float = 0.0
    strength: float = 0.2
    frequency: float = 0.8


def wind_targets(asset, wind: WindParams, data: WindData | None = None) -> np.ndarray:
    """(L, K, 3) float64: the asset's MLS targets with every leaf turned by the wind about its
    axis through its pivot, each instance's local frame (what the CPU evaluator deforms; the GLSL
    deformer turns the evaluated point instead, the same by MLS's linearity)."""
    w = data if data is not None else wind_data(asset)
    ang = wind_angles(w.phases, wind.time, wind.strength, wind.frequency)
    return rotate_about(np.asarray(asset.targets, np.float64), w.pivots_local, w.axes_local, ang)


def wind_angles(phases: np.ndarray, time: float, strength: float, frequency: float) -> np.ndarray:
    """(L,) float64 radians each leaf is turned about its axis at ``time`` (seconds):
    ``strength * sin(2 pi (frequency * time + phase))``."""
    return float(strength) * np.sin(2.0 * np.pi * (float(frequency) * float(time)
                                                   + np.asarray(phases, np.float64)))


def rotate_about(points: np.ndarray, pivots: np.ndarray, axes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(L, N, 3) float64: each leaf's points (L, N, 3) turned by ``angles`` (L,) about the line
    through ``pivots`` (L, 3) along unit ``axes`` (L, 3) (Rodrigues' formula)."""
    v = np.asarray(points, np.float64) - pivots[:, None]
    u = np.asarray(axes, np.float64)[:, None]
    c, s = np.cos(angles)[:, None, None], np.sin(angles)[:, None, None]
    return (pivots[:, None] + v * c + np.cross(u, v) * s
            + u * (np.sum(u * v, axis=2, keepdims=True)) * (1.0 - c))
