"""Replayable manual edits: the ``edits.json`` file and :func:`apply_edits`.

A session in the viewer (``leaffit-usd edit``) records every operation as data; a pipeline stores
``edits.json`` beside the capture and re-runs ``leaffit-usd segment|convert INPUT --edits
edits.json`` to get exactly the same labels. Format (version 1)::

    {
      "format": "leaffit-usd-edits", "version": 1,
      "input": {"name": "plant.ply", "sha256": "<hex of the input file's bytes>", "gaussians": N},
      "base_labels": {"sha256": "<hex of the starting labels, int32 LE, file order>", "leaves": L},
      "geodesics": {"height": H, "samples": 8192, "normals": "smallest-axis"},
      "operations": [
        {"op": "brush", "centers": [1204, 1311], "radius": 0.05, "mode": "add"},
        {"op": "assign", "label": "new"},
        {"op": "drag", "source": 88, "target": 4051, "mode": "replace"},
        {"op": "assign", "label": 3},
        {"op": "merge", "labels": [2, 5]}, {"op": "delete", "label": 4},
        {"op": "select_leaf", "label": 1, "mode": "replace"}, {"op": "split", "label": 1},
        {"op": "split_at", "seeds": [5120, 733]},
        {"op": "clear"}
      ]
    }

* ``split_at`` is the editor's click-to-split: the leaf under both seeds is partitioned by which
  seed is geodesically nearer (the same sampled heat geodesics as drag and brush), the part
  nearer the second seed becoming a new leaf.
* Gaussian indices (``source``, ``target``, ``centers``, ``seeds``) are positions in the input FILE (the
  identity of a Gaussian everywhere), not in a cloud with invalid Gaussians dropped.
* ``radius`` is a geodesic radius in working units (plant height = 1); ``geodesics.height`` is
  the plant height in input units the session used, so replay does not depend on how the up
  axis or the root are estimated. ``geodesics.normals`` is ``"smallest-axis"`` when the
  geodesics were orientation-aware (each Gaussian's smallest-scale axis as its normal, as the
  automatic segmentation does) or null.
* Labels in operations are the session's labels (gaps allowed); the result is renumbered 1..L
  in order (:func:`leaffit_usd.segment.manual.compact_labels`).
* Refused (``UserError``, one clear line): a different input file (hash), indices out of range or
  on a Gaussian dropped at load, unknown operations or malformed fields. Replayed on top of
  different starting labels than the session had (``base_labels``), the edits still apply, with a
  warning.

Distances are computed on the cloud's centres in the input frame as loaded (``cloud.means``), so
the replay does the same floating-point work as the session and gives bit-identical labels.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from leaffit_usd.errors import InputFileError, UserError
from leaffit_usd.io_util import atomic_write_bytes, file_sha256

log = logging.getLogger("leaffit_usd")

FORMAT = "leaffit-usd-edits"
VERSION = 1
NORMALS = "smallest-axis"  # default: orientation-aware geodesics, like the automatic segmentation
_INDEX_FIELDS = {"drag": ("source", "target"), "brush": ("centers",), "split_at": ("seeds",)}


@dataclass
class Edits:
    """A recorded editing session (file-order indices).

    input_sha256 : hex SHA-256 of the input file the session ran on
    n_gaussians : number of Gaussians in that file (``GaussianCloud.file_count``)
    height : plant height in input units used to normalise distances (> 0)
    n_samples : size of the geodesic subsample (N_s)
    operations : list of operation dicts (see :data:`leaffit_usd.segment.manual.OPERATIONS`)
    base_labels_sha256 : hash of the starting labels (see :func:`labels_sha256`), or None
    base_leaves : leaf count of the starting labels
    input_name : file name of the input (informative only)
    normals : "smallest-axis" (orientation-aware geodesics) or None
    """

    input_sha256: str
    n_gaussians: int
    height: float
    n_samples: int
    operations: list = field(default_factory=list)
    base_labels_sha256: str | None = None
    base_leaves: int = 0
    input_name: str = ""
    normals: str | None = NORMALS

    def to_json(self) -> dict:
        return {
            "format": FORMAT, "version": VERSION,
            "input": {"name": self.input_name, "sha256": self.input_sha256, "gaussians": self.n_gaussians},
            "base_labels": {"sha256": self.base_labels_sha256, "leaves": self.base_leaves},
            "geodesics": {"height": self.height, "samples": self.n_samples, "normals": self.normals},
            "operations": self.operations,
        }


def labels_sha256(labels_file_order: np.ndarray) -> str:
    """Hex SHA-256 of labels as little-endian int32 in file order (identifies a segmentation)."""
    return hashlib.sha256(np.asarray(labels_file_order, "<i4").tobytes()).hexdigest()


def save_edits(edits: Edits, path) -> None:
    """Write ``edits`` as indented JSON, atomically."""
    text = json.dumps(edits.to_json(), indent=1)
    atomic_write_bytes(path, (text + "\n").encode())


def parse_edits(data, source: str = "edits") -> Edits:
    """Validate the structure of a decoded edits.json (dict) and return :class:`Edits`."""
    def bad(problem):
        return InputFileError(source, problem)

    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise bad(f"not a leaffit-usd edits file (expected \"format\": \"{FORMAT}\")")
    if data.get("version") != VERSION:
        raise bad(f"edits version {data.get('version')!r} is not supported (this leaffit-usd reads version {VERSION})")
    try:
        inp, geo = data["input"], data["geodesics"]
        sha, n = inp["sha256"], inp["gaussians"]
        height, samples = geo["height"], geo["samples"]
        ops = data["operations"]
    except (KeyError, TypeError) as e:
        raise bad(f"missing field {e}") from None
    if not isinstance(sha, str) or len(sha) != 64:
        raise bad("input.sha256 must be a 64-character hex string")
    if not isinstance(n, int) or n <= 0:
        raise bad(f"input.gaussians must be a positive integer, got {n!r}")
    if not isinstance(height, (int, float)) or not np.isfinite(height) or height <= 0:
        raise bad(f"geodesics.height must be a positive number, got {height!r}")
    if not isinstance(samples, int) or samples <= 0:
        raise bad(f"geodesics.samples must be a positive integer, got {samples!r}")
    normals = geo.get("normals")
    if normals not in (None, NORMALS):
        raise bad(f"geodesics.normals must be null or \"{NORMALS}\", got {normals!r}")
    if not isinstance(ops, list) or not all(isinstance(o, dict) for o in ops):
        raise bad("operations must be a list of objects")
    for i, op in enumerate(ops):
        for name in _INDEX_FIELDS.get(op.get("op"), ()):
            vals = op.get(name)
            vals = vals if isinstance(vals, list) else [vals]
            for v in vals:
                if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < n:
                    raise bad(f"operation {i} ({op.get('op')}): {name} {v!r} is not a Gaussian index "
                              f"in [0, {n}) — the edits do not fit this input")
    base = data.get("base_labels") or {}
    return Edits(input_sha256=sha.lower(), n_gaussians=n, height=float(height), n_samples=samples,
                 operations=ops, base_labels_sha256=base.get("sha256"),
                 base_leaves=int(base.get("leaves") or 0), input_name=str(inp.get("name", "")),
                 normals=normals)


def load_edits(path, cloud_or_file) -> Edits:
    """Read and check ``edits.json`` against the input it will be applied to.

    path : the edits file. cloud_or_file : the input file path (its SHA-256 must match the one
    recorded) or a loaded ``GaussianCloud`` (then only the Gaussian count is checked — prefer the
    path). Raises ``InputFileError``/``UserError`` with a one-line reason when the edits do not fit.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputFileError(path, "no such edits file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputFileError(path, f"not readable as JSON ({e})") from None
    edits = parse_edits(data, str(path))
    if isinstance(cloud_or_file, (str, os.PathLike)):
        sha = file_sha256(cloud_or_file)
        if sha != edits.input_sha256:
            raise InputFileError(path, f"was recorded on a different input file (sha256 "
                                       f"{edits.input_sha256[:12]}…, but {Path(cloud_or_file).name} "
                                       f"has {sha[:12]}…); refusing to apply")
    else:
        count = int(cloud_or_file.file_count)
        if count != edits.n_gaussians:
            raise InputFileError(path, f"was recorded on an input with {edits.n_gaussians} Gaussians, "
                                       f"this one has {count}; refusing to apply")
    return edits


def to_cloud_operations(operations, cloud) -> list[dict]:
    """Operations with file indices -> cloud indices (Gaussians dropped at load are refused)."""
    inverse = np.full(int(cloud.file_count), -1, np.int64)
    inverse[cloud.file_index] = np.arange(len(cloud))
    out = []
    for i, op in enumerate(operations):
        op = dict(op)
        for name in _INDEX_FIELDS.get(op.get("op"), ()):
            vals = op.get(name)
            single = not isinstance(vals, list)
            mapped = []
            for v in ([vals] if single else vals):
                if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < len(inverse):
                    raise UserError(f"edits operation {i} ({op.get('op')}): {name} {v!r} is out of range "
                                    f"[0, {len(inverse)}) for this input")
                if inverse[v] < 0:
                    raise UserError(f"edits operation {i} ({op.get('op')}): Gaussian {v} was dropped at "
                                    f"load (invalid values), it cannot be used")
                mapped.append(int(inverse[v]))
            op[name] = mapped[0] if single else mapped
        out.append(op)
    return out


def to_file_operations(operations, cloud) -> list[dict]:
    """Operations with cloud indices -> file indices (for saving)."""
    out = []
    for op in operations:
        op = dict(op)
        for name in _INDEX_FIELDS.get(op.get("op"), ()):
            vals = op[name]
            op[name] = ([int(cloud.file_index[v]) for v in vals] if isinstance(vals, list)
                        else int(cloud.file_index[vals]))
        out.append(op)
    return out


def apply_edits(labels, cloud, edits: Edits, solver_factory=None, geodesics=None) -> np.ndarray:
    """Replay ``edits`` on ``labels`` and return the edited labels.

    labels : (N,) int, cloud order (one per Gaussian of ``cloud``; 0 = stem)
    cloud : GaussianCloud as loaded from the input file (input frame — distances are computed on
        ``cloud.means`` exactly as in the interactive session)
    edits : from :func:`load_edits`
    solver_factory, geodesics : see :class:`~leaffit_usd.segment.manual.ManualSegmenter`
    Returns (N,) int32 labels, cloud order, renumbered 1..L.
    """
    from leaffit_usd.segment.manual import ManualSegmenter

    labels = np.asarray(labels)
    if labels.shape != (len(cloud),):
        raise UserError(f"apply_edits: expected {len(cloud)} labels (one per Gaussian), got shape {labels.shape}")
    if int(cloud.file_count) != edits.n_gaussians:
        raise UserError(f"edits were recorded on an input with {edits.n_gaussians} Gaussians, "
                        f"this one has {cloud.file_count}; refusing to apply")
    if edits.base_labels_sha256:
        base = labels_sha256(cloud.to_file_order(labels.astype(np.int32)))
        if base != edits.base_labels_sha256:
            log.warning("edits were recorded on different starting labels (%d leaves then, %d now); "
                        "applying them anyway — check the result", edits.base_leaves,
                        int(labels.max(initial=0)))
    ops = to_cloud_operations(edits.operations, cloud)
    seg = ManualSegmenter(cloud.means, labels, edits.height, geodesics=geodesics,
                          n_samples=edits.n_samples, solver_factory=solver_factory,
                          normals=flat_normals(cloud) if edits.normals else None)
    return seg.replay(ops)


def apply_edits_file(labels, cloud, edits_path, input_path, solver_factory=None) -> np.ndarray:
    """One call for commands: load ``edits_path`` (checked against ``input_path``) and apply it.

    labels : (N,) cloud order; cloud : as loaded from ``input_path`` (input frame).
    Returns (N,) int32 edited labels, cloud order.
    """
    edits = load_edits(edits_path, input_path)
    log.info("applying %d manual edit operations from %s", len(edits.operations), edits_path)
    return apply_edits(labels, cloud, edits, solver_factory=solver_factory)


def add_edits_argument(parser) -> None:
    """Add ``--edits EDITS.json`` to a command's parser (segment, convert)."""
    parser.add_argument(
        "--edits", metavar="EDITS.json", default=None,
        help="replay manual segmentation edits recorded by 'leaffit-usd edit' (refused if they "
             "were recorded on a different input file)")


def flat_normals(cloud) -> np.ndarray:
    """(N, 3) float64 normals, input frame: each Gaussian's smallest-scale axis, NaN where the
    Gaussian is not flat (the automatic segmentation's ``working_normals`` in the input frame)."""
    from leaffit_usd.segment.auto import working_normals

    return working_normals(cloud, None)


def plant_frame(cloud) -> tuple[float, np.ndarray]:
    """(height, up) of a plant: its height in input units and its (3,) unit up axis, input frame.

    Uses the pipeline's own frame (``leaffit_usd.splats.frame.make_frame``: estimated up, root,
    height of the main blob above the root), so a brush radius of 0.05 means 5% of the same
    height the automatic segmentation's parameters refer to. Falls back to the bounding box's
    largest extent and +Z. The height is recorded in edits.json; replay never recomputes it.
    """
    points = np.asarray(cloud.means, np.float64)
    try:
        from leaffit_usd.splats.frame import make_frame

        frame = make_frame(cloud).frame
        height, up = float(frame.height), np.asarray(frame.up, np.float64)
    except ImportError:  # pragma: no cover - the foundation always provides make_frame
        height, up = float(np.ptp(points, axis=0).max()), np.array([0.0, 0.0, 1.0])
    if not np.isfinite(height) or height <= 0:
        height = float(np.ptp(points, axis=0).max()) or 1.0
    return height, up
