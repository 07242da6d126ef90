"""The editor's live leaf preview: the template leaf deformed by MLS onto one instance.

What it draws is what ``convert`` builds for that instance, by the project's own code, on a fast
path:

* the **template** is the leaf ``fit.register.fit_leaves`` chooses ("auto") on the segmentation
  the editor starts from (chosen once, with ``optimize=False``: the choice does not optimise);
  its Gaussians stay the template for the whole editing run, whatever the edits do to them;
* the **fit** of an instance is ``fit_leaves`` on the template and that instance alone (labels 1
  and 2 of a two-leaf cloud), with :data:`PREVIEW_FIT`: no Adam steps (so no depth renderer),
  the Gauss-Newton refinement (3 iterations, no outline term, which renders silhouettes), and
  smaller point caps. ``convert`` runs 200 Adam steps and 10 refinements on the full plant;
* the **sheet** is a grid over the template's denoised points in its own leaf frame (cells a
  24th of the leaf's length, kept where points are), the preview's stand-in for the template
  mesh ``mesh.template`` bakes (UVs, outline and texture are not needed to see the fit);
* the sheet is deformed and placed by ``runtime.evaluator.LeafEvaluator`` (``fit.mls``, the one
  MLS implementation) with the instance's targets and its leaf -> working -> display transform.

Frames: the session's *display* frame (``(x_input - centre) / height``) for what the page gets;
the fit runs in the working frame (``splats.frame.Frame``).
"""
from __future__ import annotations

import hashlib
import logging
import threading
import time
from dataclasses import dataclass

import numpy as np

log = logging.getLogger("leaffit_usd")

#: FitParams overrides of the preview's fit (see the module docstring)
PREVIEW_FIT = {"steps": 0, "refine": 3, "outline_weight": 0.0, "leaf_gaussians": 8192,
               "refine_points": 4096, "max_points": 512}
GRID_CELLS = 24          # sheet cells along the template leaf's longest side
MIN_LEAF_GAUSSIANS = 64  # fewer than this: no preview (a fit needs K controls and a frame)


@dataclass
class LeafMesh:
    """One previewed leaf. vertices : (V, 3) float32, display frame; faces : (F, 3) uint32;
    edges : (E, 2) uint32 (the sheet's grid lines, for a wireframe); label : the instance;
    fallback : the fit fell back to rigid; error : its Chamfer error, working units;
    ms : time to compute it."""

    label: int
    vertices: np.ndarray
    faces: np.ndarray
    edges: np.ndarray
    fallback: bool
    error: float
    ms: float


def sheet_grid(points: np.ndarray, cells: int = GRID_CELLS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A grid sheet over leaf points in their leaf frame (x along the leaf, z its normal).

    points : (M, 3) float, leaf local frame. Returns (vertices (V, 3) float64, same frame;
    faces (F, 3) int64; edges (E, 2) int64): grid nodes with a point within a cell's reach,
    each lifted to the mean height of its nearest points; quads with four kept corners.
    """
    from scipy.spatial import cKDTree

    p = np.asarray(points, np.float64)
    lo, hi = p[:, :2].min(0), p[:, :2].max(0)
    h = max(float((hi - lo).max()) / cells, 1e-9)
    nx, ny = (np.ceil((hi - lo) / h).astype(int) + 1)
    gx, gy = np.meshgrid(lo[0] + h * np.arange(nx), lo[1] + h * np.arange(ny), indexing="ij")
    nodes = np.c_[gx.ravel(), gy.ravel()]
    tree = cKDTree(p[:, :2])
    d, idx = tree.query(nodes, k=min(8, len(p)))
    d, idx = d.reshape(len(nodes), -1), idx.reshape(len(nodes), -1)
    keep = d[:, 0] <= 0.75 * h
    z = p[idx, 2].mean(1)
    vid = np.full(len(nodes), -1, np.int64)
    vid[keep] = np.arange(int(keep.sum()))
    verts = np.c_[nodes[keep], z[keep]]
    g = vid.reshape(nx, ny)
    a, b, c, e = g[:-1, :-1], g[1:, :-1], g[1:, 1:], g[:-1, 1:]
    quad = (a >= 0) & (b >= 0) & (c >= 0) & (e >= 0)
    faces = np.concatenate([np.c_[a[quad], b[quad], c[quad]], np.c_[a[quad], c[quad], e[quad]]])
    hor = (g[:-1, :] >= 0) & (g[1:, :] >= 0)
    ver = (g[:, :-1] >= 0) & (g[:, 1:] >= 0)
    edges = np.concatenate([np.c_[g[:-1, :][hor], g[1:, :][hor]], np.c_[g[:, :-1][ver], g[:, 1:][ver]]])
    return verts, faces.astype(np.int64), edges.astype(np.int64)


class LeafPreviewer:
    """Fits and deforms the template onto instances of one plant (heavy set-up once, then one
    fit per query; results cached by the instance's Gaussians).

    working : GaussianCloud, working frame, session (cloud) order
    initial_labels : (N,) int, the labels the editor started from (choose the template)
    working_to_display : (4, 4) float64 similarity, working -> display frame
    """

    def __init__(self, working, initial_labels, working_to_display: np.ndarray):
        self.working = working
        self.initial = np.asarray(initial_labels, np.int32)
        self.to_display = np.asarray(working_to_display, np.float64)
        self.template_gaussians: np.ndarray | None = None
        self._sheet = None          # (controls key, LeafEvaluator, faces, edges)
        self._cache: dict[tuple, LeafMesh] = {}
        self._lock = threading.Lock()

    def _params(self, **over):
        from leaffit_usd.fit.params import FitParams

        return FitParams(**{**PREVIEW_FIT, **over})

    def choose_template(self) -> np.ndarray:
        """(T,) int64 the template leaf's Gaussians (session order): fit's "auto" choice on the
        starting labels (computed once)."""
        if self.template_gaussians is None:
            labels = self.initial
            if labels.max(initial=0) == 0:
                raise LookupError("no leaf to take the template from (every Gaussian is unassigned)")
            from leaffit_usd.fit.register import fit_leaves
            from leaffit_usd.segment.result import Segmentation

            t0 = time.perf_counter()
            fits = fit_leaves(self.working, Segmentation(labels=labels, root_index=0),
                              self._params(optimize=False))
            self.template_gaussians = np.flatnonzero(labels == fits.template_label).astype(np.int64)
            log.info("edit: preview template is leaf %d (%d Gaussians), chosen in %.2f s",
                     fits.template_label, len(self.template_gaussians), time.perf_counter() - t0)
        return self.template_gaussians

    def preview(self, label: int, members: np.ndarray) -> LeafMesh:
        """The fitted leaf of the instance made of ``members`` ((M,) int session indices).
        Raises LookupError when there is nothing to fit (too few Gaussians, no template)."""
        members = np.asarray(members, np.int64)
        if len(members) < MIN_LEAF_GAUSSIANS:
            raise LookupError(f"leaf {label} has {len(members)} Gaussians, too few to fit "
                              f"(at least {MIN_LEAF_GAUSSIANS})")
        key = (int(label), hashlib.sha1(members.tobytes()).hexdigest())
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                return hit
            out = self._compute(int(label), members)
            if len(self._cache) > 64:
                self._cache.pop(next(iter(self._cache)))
            self._cache[key] = out
            return out

    def _compute(self, label: int, members: np.ndarray) -> LeafMesh:
        from leaffit_usd.fit.register import fit_leaves
        from leaffit_usd.runtime.evaluator import LeafEvaluator
        from leaffit_usd.segment.result import Segmentation

        t0 = time.perf_counter()
        tmpl = self.choose_template()
        idx = np.concatenate([tmpl, members])
        labels = np.r_[np.ones(len(tmpl), np.int32), np.full(len(members), 2, np.int32)]
        fits = fit_leaves(self.working.subset(idx), Segmentation(labels=labels, root_index=0),
                          self._params(template=1))
        ctl = np.asarray(fits.template_controls, np.float64)
        ck = (ctl.tobytes(), float(fits.sigma), float(fits.reg))
        if self._sheet is None or self._sheet[0] != ck:   # built once: the template is fixed
            verts, faces, edges = sheet_grid(fits.template_points)
            self._sheet = (ck, LeafEvaluator(verts, ctl, fits.sigma, fits.reg), faces, edges)
        _, ev, faces, edges = self._sheet
        m = self.to_display @ np.asarray(fits.leaf_to_working[1], np.float64)
        v = ev.evaluate(np.asarray(fits.targets[1:2], np.float64), m[None])[0]
        return LeafMesh(label=label, vertices=v.astype(np.float32), faces=faces.astype(np.uint32),
                        edges=edges.astype(np.uint32), fallback=bool(fits.fallback[1]),
                        error=float(fits.errors[1]), ms=(time.perf_counter() - t0) * 1e3)
