"""Manual segmentation: the paper's geodesic *drag* and *brush* tools, as replayable operations.

Paper, Sec. "Manual Segmentation":

* drag — source Gaussian ``p`` at the press, target ``d`` under the cursor; a Gaussian ``g`` is
  selected when ``D_p[g] <= D_p[d]``;
* brush — centre ``d`` under the cursor, geodesic radius ``r``; ``g`` is selected when
  ``D_d[g] <= r`` (add or erase);
* selections are assigned to an existing leaf, a new leaf, or the stem (label 0).

Everything a user does is an *operation* (a plain dict, see :data:`OPERATIONS`) applied by
:class:`ManualSegmenter`; the viewer and :func:`leaffit_usd.segment.edits.apply_edits` run the
very same code, so replaying a session's operations gives the session's labels exactly.

Geodesics: heat-method distances (``GeodesicSolver``, factored once) on a farthest-point
subsample of ``n_samples`` Gaussians (the paper's N_s = 8192), extended to every Gaussian by one
min-plus step over its ``k`` nearest samples, ``D[g] = min_j (D_s[s_j] + |g - s_j|)`` (a
shortest-path continuation; it is 0 at the source sample and continuous across Voronoi cells).
A solve on 8192 samples takes ~5 ms, the extension ~2 ms on 100k Gaussians, and distances are
cached per source sample, so an interactive update stays far below the 100 ms budget.

Indices in this module are positions in the cloud the segmenter was built on (cloud order);
:mod:`leaffit_usd.segment.edits` converts to and from the file order stored in ``edits.json``.
Distances and radii are in working units (plant height = 1): input-frame distances divided by
``height``.
"""
from __future__ import annotations

import logging
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from leaffit_usd.errors import ParameterError, UserError

log = logging.getLogger("leaffit_usd")

N_SAMPLES = 8192  # the paper's N_s: density of the geodesic graph
K_EXTEND = 4  # samples used to extend sample distances to every Gaussian
FULL_CACHE = 8  # full (N,) distance fields kept (a drag reuses its source's field every update)

#: Operation kinds and their fields (indices are cloud indices here, file indices in edits.json).
OPERATIONS = {
    "drag": "source: int, target: int, mode: replace|add|erase — select D_source[g] <= D_source[target]",
    "brush": "centers: [int], radius: float (working units), mode: add|erase|replace — D_c[g] <= radius",
    "select_leaf": "label: int, mode: replace|add|erase — select a whole leaf (or the stem, 0)",
    "clear": "empty the selection",
    "assign": "label: int >= 0 | 'new' — selected Gaussians get this label (0 = stem); clears the selection",
    "merge": "labels: [int, ...] — every listed leaf gets the first label",
    "delete": "label: int >= 1 — the leaf's Gaussians go back to the stem",
    "split": "label: int >= 1 — the selected Gaussians of that leaf become a new leaf",
    "split_at": "seeds: [int, int] — two clicks on one leaf that is two merged leaves: its Gaussians "
                "geodesically nearer the second seed become a new leaf (ties stay)",
}
SELECT_MODES = ("replace", "add", "erase")


def default_solver_factory():
    """The project's heat-method solver class, ``leaffit_usd.geometry.heat.GeodesicSolver``."""
    from leaffit_usd.geometry.heat import GeodesicSolver

    return GeodesicSolver


class SampledGeodesics:
    """Heat geodesic distances from any Gaussian, solved on a subsample and cached per source.

    points : (N, 3) float, input frame (any frame; distances come out in its units / ``height``)
    height : float > 0, plant height in the points' units (distances are divided by it)
    n_samples : size of the farthest-point subsample the solver is factored on
    solver_factory : callable ``(points (S, 3)[, normals (S, 3)]) -> solver`` with
        ``.distance(source: int) -> (S,)`` (default: :func:`default_solver_factory`)
    normals : optional (N, 3) unit normals, same frame (NaN rows = unknown): passed to the solver
        for orientation-aware geodesics (a leaf lying on another is not short-cut), as the
        automatic segmentation does (``leaffit_usd.segment.auto.working_normals``)
    cache_size : distance fields kept (per source sample, (S,) float64 each)
    """

    def __init__(self, points, height: float, n_samples: int = N_SAMPLES, solver_factory=None,
                 k: int = K_EXTEND, cache_size: int = 1024, normals=None):
        from scipy.spatial import cKDTree

        from leaffit_usd.geometry.sampling import farthest_point_sampling

        points = np.asarray(points, np.float64)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
            raise ParameterError("points", "a non-empty (N, 3) array", points.shape)
        if not (np.isfinite(height) and height > 0):
            raise ParameterError("height", "a positive plant height", height)
        self.height = float(height)
        n = len(points)
        if n <= n_samples:
            self.samples = np.arange(n, dtype=np.int64)
        else:
            self.samples = farthest_point_sampling(points, int(n_samples))
        factory = solver_factory or default_solver_factory()
        if normals is None:
            self.solver = factory(points[self.samples])
        else:
            normals = np.asarray(normals, np.float64)
            if normals.shape != points.shape:
                raise ParameterError("normals", f"an array shaped like points {points.shape}", normals.shape)
            self.solver = factory(points[self.samples], normals[self.samples])
        k = int(min(k, len(self.samples)))
        tree = cKDTree(points[self.samples])
        dist, idx = tree.query(points, k=k)
        self._nn_idx = np.asarray(idx, np.int64).reshape(n, k)
        self._nn_dist = (np.asarray(dist, np.float64).reshape(n, k) / self.height).astype(np.float32)
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._cache_size = int(cache_size)
        self._full: OrderedDict[int, np.ndarray] = OrderedDict()  # (N,) fields of recent sources
        self.n = n

    def source_sample(self, g: int) -> int:
        """Index into ``samples`` of the sample nearest to Gaussian ``g`` (the heat source used)."""
        return int(self._nn_idx[g, 0])

    def sample_distance(self, s: int) -> np.ndarray:
        """(S,) float64 working-unit distances from sample ``s`` to every sample (cached)."""
        d = self._cache.get(s)
        if d is None:
            d = np.asarray(self.solver.distance(int(s)), np.float64).reshape(-1) / self.height
            d = np.where(np.isfinite(d), d, np.inf)  # disconnected pieces: unreachable
            d = np.maximum(d, 0.0)
            d[s] = 0.0
            self._cache[s] = d
            if len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(s)
        return d

    def distance(self, g: int) -> np.ndarray:
        """(N,) float32 working-unit geodesic distance from Gaussian ``g`` to every Gaussian."""
        if not 0 <= int(g) < self.n:
            raise ParameterError("gaussian", f"an index in [0, {self.n})", g)
        s = self.source_sample(int(g))
        full = self._full.get(s)
        if full is None:
            ds = self.sample_distance(s).astype(np.float32)
            full = (ds[self._nn_idx] + self._nn_dist).min(axis=1)
            full.flags.writeable = False  # shared by the cache: never modified in place
            self._full[s] = full
            if len(self._full) > FULL_CACHE:
                self._full.popitem(last=False)
        else:
            self._full.move_to_end(s)
        return full


@dataclass
class EditState:
    """labels : (N,) int32, cloud order; selection : (N,) bool."""

    labels: np.ndarray
    selection: np.ndarray

    def copy(self) -> "EditState":
        return EditState(self.labels.copy(), self.selection.copy())


def compact_labels(labels: np.ndarray) -> np.ndarray:
    """Renumber leaf labels to 1..L keeping their order (0 stays 0). (N,) int32."""
    labels = np.asarray(labels)
    used = np.unique(labels[labels > 0])
    table = np.zeros(int(labels.max(initial=0)) + 1, np.int32)
    table[used] = np.arange(1, len(used) + 1, dtype=np.int32)
    return table[np.maximum(labels, 0)]


class ManualSegmenter:
    """An editing session on one cloud: current labels, a selection, operations, undo/redo.

    points : (N, 3) float, input frame (Gaussian centres, cloud order)
    labels : (N,) int, starting labels (0 = stem / unassigned)
    height : float > 0, plant height in input units (brush radii are fractions of it)
    geodesics : optional prebuilt :class:`SampledGeodesics` (else built from ``points``)
    n_samples, solver_factory, normals : passed to :class:`SampledGeodesics`
    """

    def __init__(self, points, labels, height: float, geodesics: SampledGeodesics | None = None,
                 n_samples: int = N_SAMPLES, solver_factory=None, normals=None):
        points = np.asarray(points)
        labels = np.asarray(labels)
        if labels.shape != (len(points),):
            raise ParameterError("labels", f"({len(points)},) labels, one per Gaussian", labels.shape)
        if labels.size and labels.min() < 0:
            raise ParameterError("labels", "labels >= 0 (0 = stem)", int(labels.min()))
        self.n = len(points)
        self.geodesics = geodesics or SampledGeodesics(points, height, n_samples, solver_factory,
                                                       normals=normals)
        self.initial = EditState(labels.astype(np.int32).copy(), np.zeros(self.n, bool))
        self.state = self.initial.copy()
        self.operations: list[dict] = []
        self._undo: list[EditState] = []  # state before each operation
        self._redo: list[tuple[dict, EditState]] = []
        self._brush_cache: tuple = (None, (), None)

    # ---- selections ---------------------------------------------------------------------
    def drag_mask(self, source: int, target: int) -> np.ndarray:
        """(N,) bool: ``D_source[g] <= D_source[target]`` (paper's drag tool)."""
        d = self.geodesics.distance(source)
        return d <= d[target]

    def brush_mask(self, centers, radius: float) -> np.ndarray:
        """(N,) bool: union over centres c of ``D_c[g] <= radius`` (working units)."""
        centers = tuple(int(c) for c in centers)
        # A stroke grows one centre at a time: reuse the previous union when it is a prefix
        # (a boolean OR, so the result is identical with or without the cache).
        r0, c0, m0 = self._brush_cache
        if r0 == radius and c0 == centers[:len(c0)] and c0:
            mask, start = m0.copy(), len(c0)
        else:
            mask, start = np.zeros(self.n, bool), 0
        for c in centers[start:]:
            mask |= self.geodesics.distance(c) <= radius
        self._brush_cache = (radius, centers, mask.copy())
        return mask

    def _check_index(self, op_no, name, g):
        if isinstance(g, bool) or not isinstance(g, (int, np.integer)) or not 0 <= g < self.n:
            raise UserError(f"operation {op_no}: {name} must be a Gaussian index in [0, {self.n}), got {g!r}")
        return int(g)

    def _check_label(self, op_no, name, v, allow_new=False, allow_stem=True):
        if allow_new and v == "new":
            return v
        ok = isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= (0 if allow_stem else 1)
        if not ok:
            want = "a leaf label >= 1" if not allow_stem else "a label >= 0 (0 = stem)"
            if allow_new:
                want += " or 'new'"
            raise UserError(f"operation {op_no}: {name} must be {want}, got {v!r}")
        return int(v)

    def _mode(self, op_no, op, default):
        mode = op.get("mode", default)
        if mode not in SELECT_MODES:
            raise UserError(f"operation {op_no}: mode must be one of {', '.join(SELECT_MODES)}, got {mode!r}")
        return mode

    def validate(self, op: dict, op_no: int | str = "?") -> dict:
        """A normalised copy of ``op`` (cloud indices); raises UserError saying what is wrong."""
        if not isinstance(op, dict) or op.get("op") not in OPERATIONS:
            kind = op.get("op") if isinstance(op, dict) else op
            raise UserError(f"operation {op_no}: unknown operation {kind!r} (expected one of {', '.join(OPERATIONS)})")
        kind = op["op"]
        if kind == "drag":
            return {"op": kind, "source": self._check_index(op_no, "source", op.get("source")),
                    "target": self._check_index(op_no, "target", op.get("target")),
                    "mode": self._mode(op_no, op, "replace")}
        if kind == "brush":
            centers = op.get("centers")
            if not isinstance(centers, list) or not centers:
                raise UserError(f"operation {op_no}: centers must be a non-empty list of Gaussian indices")
            r = op.get("radius")
            if isinstance(r, bool) or not isinstance(r, (int, float)) or not np.isfinite(r) or r < 0:
                raise UserError(f"operation {op_no}: radius must be a number >= 0 (working units), got {r!r}")
            return {"op": kind, "centers": [self._check_index(op_no, "centers[]", c) for c in centers],
                    "radius": float(r), "mode": self._mode(op_no, op, "add")}
        if kind == "select_leaf":
            return {"op": kind, "label": self._check_label(op_no, "label", op.get("label")),
                    "mode": self._mode(op_no, op, "replace")}
        if kind == "clear":
            return {"op": kind}
        if kind == "assign":
            return {"op": kind, "label": self._check_label(op_no, "label", op.get("label"), allow_new=True)}
        if kind == "merge":
            labels = op.get("labels")
            if not isinstance(labels, list) or len(labels) < 2:
                raise UserError(f"operation {op_no}: labels must list at least two leaves to merge")
            return {"op": kind, "labels": [self._check_label(op_no, "labels[]", v, allow_stem=False) for v in labels]}
        if kind == "split_at":
            seeds = op.get("seeds")
            if not isinstance(seeds, list) or len(seeds) != 2:
                raise UserError(f"operation {op_no}: seeds must list two Gaussian indices, one per leaf")
            a, b = (self._check_index(op_no, "seeds[]", g) for g in seeds)
            return {"op": kind, "seeds": [a, b]}
        # delete, split
        return {"op": kind, "label": self._check_label(op_no, "label", op.get("label"), allow_stem=False)}

    @staticmethod
    def _combine(selection, mask, mode):
        if mode == "replace":
            return mask
        if mode == "add":
            return selection | mask
        return selection & ~mask

    def _run(self, state: EditState, op: dict) -> EditState:
        """Apply a validated ``op`` to ``state`` and return the new state (``state`` untouched)."""
        kind = op["op"]
        labels, sel = state.labels, state.selection
        if kind == "drag":
            return EditState(labels, self._combine(sel, self.drag_mask(op["source"], op["target"]), op["mode"]))
        if kind == "brush":
            return EditState(labels, self._combine(sel, self.brush_mask(op["centers"], op["radius"]), op["mode"]))
        if kind == "select_leaf":
            return EditState(labels, self._combine(sel, labels == op["label"], op["mode"]))
        if kind == "clear":
            return EditState(labels, np.zeros(self.n, bool))
        labels = labels.copy()
        if kind == "assign":
            target = op["label"]
            if target == "new":
                target = int(labels.max(initial=0)) + 1 if sel.any() else 0
            if sel.any():
                labels[sel] = target
            return EditState(labels, np.zeros(self.n, bool))
        if kind == "merge":
            into = op["labels"][0]
            labels[np.isin(labels, op["labels"][1:])] = into
            return EditState(labels, sel)
        if kind == "delete":
            labels[labels == op["label"]] = 0
            return EditState(labels, sel)
        if kind == "split_at":
            part = self.split_part(state.labels, *op["seeds"])
            labels[part] = int(labels.max(initial=0)) + 1
            return EditState(labels, np.zeros(self.n, bool))
        if kind == "split":
            part = sel & (labels == op["label"])
            if part.any():
                labels[part] = int(labels.max(initial=0)) + 1
            return EditState(labels, np.zeros(self.n, bool))
        raise AssertionError(kind)  # validate() rejects unknown kinds

    def split_part(self, labels: np.ndarray, a: int, b: int) -> np.ndarray:
        """(N,) bool: the Gaussians of seed ``a``'s leaf that are geodesically nearer to seed ``b``
        than to ``a`` (``D_b[g] < D_a[g]``; ties stay with ``a``). The leaf is
        ``labels[a]``, which must be a leaf (>= 1) and ``labels[b]``'s too (UserError)."""
        la, lb = int(labels[a]), int(labels[b])
        if la == 0 or lb == 0:
            raise UserError("split_at: both clicks must be on a leaf (one is on the stem / unassigned)")
        if la != lb:
            raise UserError(f"split_at: the two clicks are on different leaves ({la} and {lb}); "
                            "click twice on the one leaf to split")
        if a == b or self.geodesics.source_sample(a) == self.geodesics.source_sample(b):
            raise UserError("split_at: the two clicks are on the same spot; click once on each leaf")
        leaf = labels == la
        return leaf & (self.geodesics.distance(b) < self.geodesics.distance(a))

    # ---- public editing API ----------------------------------------------------------------
    def preview(self, op: dict) -> np.ndarray:
        """(N,) bool selection ``op`` would give, without recording it (interactive feedback)."""
        return self._run(self.state, self.validate(op)).selection

    def apply(self, op: dict, op_no: int | str = "?") -> dict:
        """Validate, apply and record ``op``; returns the normalised operation. Clears redo."""
        op = self.validate(op, op_no)
        new = self._run(self.state, op)
        self._undo.append(self.state)
        self.state = new
        self.operations.append(op)
        self._redo.clear()
        return op

    def undo(self) -> bool:
        """Revert the last operation (False when there is none)."""
        if not self._undo:
            return False
        self._redo.append((self.operations.pop(), self.state))
        self.state = self._undo.pop()
        return True

    def redo(self) -> bool:
        """Re-apply the last undone operation (False when there is none)."""
        if not self._redo:
            return False
        op, state = self._redo.pop()
        self._undo.append(self.state)
        self.operations.append(op)
        self.state = state
        return True

    @property
    def can_undo(self) -> bool:
        return bool(self._undo)

    @property
    def can_redo(self) -> bool:
        return bool(self._redo)

    @property
    def labels(self) -> np.ndarray:
        """(N,) int32 current labels, cloud order (session numbering, may have gaps)."""
        return self.state.labels

    @property
    def selection(self) -> np.ndarray:
        """(N,) bool current selection."""
        return self.state.selection

    def final_labels(self) -> np.ndarray:
        """(N,) int32 current labels renumbered 1..L (what is saved)."""
        return compact_labels(self.state.labels)

    def replay(self, operations) -> np.ndarray:
        """Apply a list of operations in order (each recorded); returns the final labels (compacted)."""
        for i, op in enumerate(operations):
            self.apply(op, op_no=i)
        return self.final_labels()
