"""Deformation metrics (LeafFit Tab. 3/4): a deformed template leaf against a target leaf.

Both surfaces are compared through area-uniform samples (``sample_surface``, trimesh). With A the
samples of the deformed template, B those of the target (ground truth), and d(x, S) the distance
from x to the nearest point of S:

* **Corr-l2**: mean nearest-neighbour error, mean_{a in A} d(a, target)
  (how far each deformed template point is from the target surface);
* **CD**: symmetric Chamfer distance with squared distances (the paper's L_chamfer form),
  mean_a d(a, target)^2 + mean_b d(b, template)^2;
* **HD**: Hausdorff distance, max(max_a d(a, target), max_b d(b, template)).
* ``corr_rev``: the reverse mean, mean_b d(b, template) (how much of the target the deformed
  template misses); (corr + corr_rev) / 2 is the symmetric mean nearest-neighbour error, the
  other common reading of "mean nearest-neighbour error" (reported beside Corr, never instead).

:func:`mesh_metrics` measures d to the other **surface** (exact closest point on its triangles,
open3d ``RaycastingScene``): distances between two independent samplings of the same surface
would add a floor of about half the sample spacing (~0.007 x10 for 10k samples of a typical
leaf here), the size of the differences being measured. :func:`point_metrics` is the
sample-to-sample version for point sets without a mesh.

Units: those of the inputs (the working frame: plant height 1). The paper reports the values
x10 (``PAPER_SCALE``); :meth:`DeformationMetrics.scaled` applies it.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from leaffit_usd.errors import ParameterError

PAPER_SCALE = 10.0


class DeformationMetrics(NamedTuple):
    """corr : Corr-l2; cd : symmetric squared Chamfer; hd : Hausdorff; corr_rev : reverse mean
    nearest-neighbour error (input units, unscaled)."""

    corr: float
    cd: float
    hd: float
    corr_rev: float = float("nan")

    @property
    def corr_sym(self) -> float:
        return 0.5 * (self.corr + self.corr_rev)

    def scaled(self, factor: float = PAPER_SCALE) -> "DeformationMetrics":
        """All values x ``factor`` (the paper's reporting convention, x10)."""
        return DeformationMetrics(self.corr * factor, self.cd * factor, self.hd * factor,
                                  self.corr_rev * factor)


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """(n, 3) float64 points, uniform by area on the mesh (vertices (V, 3), faces (F, 3) int).

    Deterministic in ``seed``. Raises ParameterError for an empty or zero-area mesh.
    """
    import trimesh

    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise ParameterError("mesh", "vertices (V, 3) and at least one face (F, 3)",
                             (v.shape, f.shape))
    if f.min() < 0 or f.max() >= len(v):
        raise ParameterError("faces", f"indices in [0, {len(v)})", (int(f.min()), int(f.max())))
    mesh = trimesh.Trimesh(v, f, process=False)
    if not mesh.area > 0:
        raise ParameterError("mesh", "a mesh with positive area", float(mesh.area))
    pts, _ = trimesh.sample.sample_surface(mesh, int(n), seed=seed)
    return np.asarray(pts, np.float64)


def point_metrics(a: np.ndarray, b: np.ndarray) -> DeformationMetrics:
    """Metrics between point samples a (deformed template, (Na, 3)) and b (target, (Nb, 3))."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.ndim != 2 or a.shape[1] != 3 or len(a) == 0:
        raise ParameterError("a", "a non-empty (N, 3) array", a.shape)
    if b.ndim != 2 or b.shape[1] != 3 or len(b) == 0:
        raise ParameterError("b", "a non-empty (N, 3) array", b.shape)
    dab, _ = cKDTree(b).query(a, k=1)
    dba, _ = cKDTree(a).query(b, k=1)
    return DeformationMetrics(float(dab.mean()), float((dab**2).mean() + (dba**2).mean()),
                              float(max(dab.max(), dba.max())), float(dba.mean()))


def surface_distance(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N,) float64 unsigned distance from each point (N, 3) to the mesh (vertices, faces)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(vertices, np.float32)),
                        o3d.core.Tensor(np.asarray(faces, np.uint32)))
    d = scene.compute_distance(o3d.core.Tensor(np.asarray(points, np.float32)))
    return d.numpy().astype(np.float64)


def mesh_metrics(pred_vertices, pred_faces, gt_vertices, gt_faces, n: int = 10000,
                 seed: int = 0) -> DeformationMetrics:
    """Metrics between a deformed template mesh and a ground-truth mesh: ``n`` area samples of
    each, their distances to the other surface (see the module doc)."""
    a = sample_surface(pred_vertices, pred_faces, n, seed)
    b = sample_surface(gt_vertices, gt_faces, n, seed + 1)
    dab = surface_distance(a, gt_vertices, gt_faces)
    dba = surface_distance(b, pred_vertices, pred_faces)
    return DeformationMetrics(float(dab.mean()), float((dab**2).mean() + (dba**2).mean()),
                              float(max(dab.max(), dba.max())), float(dba.mean()))
