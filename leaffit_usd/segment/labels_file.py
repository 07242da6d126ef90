"""The segmentation file (``labels.npz``): its one writer and its one reader.

Contents (numpy .npz, every array in FILE order, one entry per Gaussian of the input file):

* ``labels`` int32 (required): 0 = stem / unassigned, 1..L = leaf instances, -1 = removed by
  isolation (or unassigned noise in a ground-truth file; any negative value counts as
  unassigned when read);
* ``root_index`` int64 (optional): the root Gaussian's index in the input file;
* ``confidence`` float64 (optional): one value in [0, 1] per leaf of the file, leaf l+1 at l;
* whatever else the writer was given (``segment`` writes the tree, the apexes, the distances,
  the isolation classes, the frame): kept verbatim, ignored by the reader.

``segment`` and the editor's Save write it; ``convert --labels`` and ``edit --labels`` read it
(:func:`cloud_labels`), so a hand-made file holding just ``labels`` is valid everywhere.
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from leaffit_usd.errors import InputFileError
from leaffit_usd.io_util import atomic_path

log = logging.getLogger("leaffit_usd")


def write_labels_file(path, labels: np.ndarray, root_index: int | None = None,
                      confidence: np.ndarray | None = None, **arrays) -> None:
    """Write a segmentation file atomically. labels : (file_count,) int, file order; root_index :
    a file index or None; confidence : (L,) per leaf or None; arrays : more arrays to keep."""
    out = {"labels": np.asarray(labels, np.int32)}
    if root_index is not None:
        out["root_index"] = np.int64(root_index)
    if confidence is not None:
        out["confidence"] = np.asarray(confidence, np.float64)
    out.update(arrays)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **out)


@dataclass(frozen=True)
class LabelsFile:
    """A segmentation file as read: labels (file_count,) int (as stored), root_index (a file
    index or None), confidence ((L,) as stored, or None)."""

    labels: np.ndarray
    root_index: int | None
    confidence: np.ndarray | None


def read_labels_file(path) -> LabelsFile:
    """Read a segmentation file. Raises InputFileError for a missing or malformed one."""
    p = Path(path)
    if not p.is_file():
        raise InputFileError(p, "no such file")
    try:
        with np.load(p, allow_pickle=False) as z:
            if "labels" not in z.files:
                raise InputFileError(p, f"no 'labels' array (found {', '.join(z.files) or 'nothing'})")
            labels = np.asarray(z["labels"])
            root = int(z["root_index"]) if "root_index" in z.files else None
            if root is None and "__json__" in z.files:
                root = json.loads(str(z["__json__"])).get("root_index")
            conf = np.asarray(z["confidence"]) if "confidence" in z.files else None
    except InputFileError:
        raise
    except Exception as e:  # noqa: BLE001 - any unreadable npz is the user's file
        raise InputFileError(p, f"not a readable .npz ({type(e).__name__}: {e})") from None
    if labels.ndim != 1 or labels.dtype.kind not in "iu":
        raise InputFileError(p, f"'labels' must be a 1-D integer array, is {labels.dtype} {labels.shape}")
    return LabelsFile(labels=labels, root_index=None if root is None else int(root), confidence=conf)


def cloud_labels(path, cloud) -> tuple[np.ndarray, int | None, np.ndarray | None]:
    """A segmentation file for ``cloud`` (a GaussianCloud or anything with ``file_index`` and
    ``file_count``): (labels (N,) int32 in cloud order, negative values as 0 and the leaves
    present renumbered 1..L; the root's cloud index or None; the renumbered leaves' confidence
    (L,) float64, or None when the file has none or it does not fit, with a warning).
    Raises InputFileError when the count does not match the input."""
    lf = read_labels_file(path)
    if len(lf.labels) != cloud.file_count:
        raise InputFileError(path, f"{len(lf.labels)} labels but the input has {cloud.file_count} "
                                   "Gaussians (one label per Gaussian, file order)")
    fi = np.asarray(cloud.file_index)
    out = lf.labels[fi].astype(np.int32)
    if out.size and out.min() < 0:  # e.g. -1 = noise in ground-truth files: treat as unassigned
        log.info("      %d Gaussians with negative labels treated as unassigned (0)", int((out < 0).sum()))
        out[out < 0] = 0
    uniq = np.unique(out[out > 0])  # renumber the leaves present 1..L (a hand-made file has gaps)
    remap = np.zeros(int(out.max(initial=0)) + 1, np.int32)
    remap[uniq] = np.arange(1, len(uniq) + 1, dtype=np.int32)
    root = None
    if lf.root_index is not None and 0 <= lf.root_index < cloud.file_count:
        hit = np.flatnonzero(fi == lf.root_index)
        root = int(hit[0]) if hit.size else None
    return remap[out], root, _confidence(path, lf, uniq)


def _confidence(path, lf: LabelsFile, kept: np.ndarray) -> np.ndarray | None:
    """The file's per-leaf confidence for the leaves ``kept`` (file leaf numbers, in the
    renumbered order), or None."""
    conf = lf.confidence
    if conf is None:
        return None
    n_file = int(lf.labels.max(initial=0))
    if conf.ndim != 1 or conf.dtype.kind not in "fiu" or len(conf) != n_file:
        log.warning("%s: ignoring its 'confidence' (%s %s; expected %d values, one per leaf)",
                    path, conf.dtype, conf.shape, n_file)
        return None
    conf = conf.astype(np.float64)
    if not np.all((conf >= 0) & (conf <= 1)):
        log.warning("%s: ignoring its 'confidence' (values outside [0, 1])", path)
        return None
    return conf[kept - 1]
