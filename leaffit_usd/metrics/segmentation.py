"""Instance segmentation metrics as the paper reports them (Results, "Segmentation Evaluation").

Instances are the leaves plus the stem as one class: ground truth ``0`` (stem incl. petioles) and
``1..L`` (leaves), prediction ``0`` (stem/unassigned) and ``1..P``. Floaters (ground truth ``-1``)
are excluded from every count. Ground-truth and predicted instances are matched one-to-one by the
Hungarian algorithm (scipy ``linear_sum_assignment``) maximising IoU; a pair counts as a match only
at IoU >= 0.5 (``MATCH_IOU``).

* Acc  : fraction of (non-floater) Gaussians whose predicted instance is matched to their
         ground-truth instance;
* mIoU : mean over ground-truth instances of the IoU with their match (0 when unmatched);
* mF1  : the same with F1 = 2|P∩G| / (|P| + |G|);
* PQ   : panoptic quality, sum of matched IoUs / (TP + FP/2 + FN/2) (Kirillov et al. 2019).
All four are in percent, as in the paper's Table 1.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from leaffit_usd.errors import ParameterError

MATCH_IOU = 0.5


@dataclass
class SegmentationScores:
    """Scores of one plant, percent. n_gt / n_pred count instances incl. the stem; tp = matches."""

    acc: float
    miou: float
    mf1: float
    pq: float
    n_gt: int
    n_pred: int
    tp: int

    def as_dict(self) -> dict:
        return dict(acc=self.acc, miou=self.miou, mf1=self.mf1, pq=self.pq, n_gt=self.n_gt,
                    n_pred=self.n_pred, tp=self.tp)


def segmentation_scores(pred: np.ndarray, gt: np.ndarray) -> SegmentationScores:
    """Acc, mIoU, mF1, PQ (percent) of predicted labels against ground truth.

    pred : (N,) int, 0 = stem/unassigned, 1..P leaves (negative values are treated as stem)
    gt : (N,) int, 0 = stem, 1..L leaves, -1 = floater (excluded)
    """
    pred = np.asarray(pred)
    gt = np.asarray(gt)
    if pred.shape != gt.shape or pred.ndim != 1:
        raise ParameterError("pred", f"a 1-D label array shaped like gt {gt.shape}", pred.shape)
    if not (np.issubdtype(pred.dtype, np.integer) and np.issubdtype(gt.dtype, np.integer)):
        raise ParameterError("labels", "integer arrays", (pred.dtype, gt.dtype))
    keep = gt >= 0
    if not keep.any():
        raise ParameterError("gt", "at least one non-floater label", "only floaters")
    g = gt[keep].astype(np.int64)
    p = np.maximum(pred[keep].astype(np.int64), 0)
    gi, g_inv = np.unique(g, return_inverse=True)
    pi, p_inv = np.unique(p, return_inverse=True)
    inter = np.zeros((len(gi), len(pi)), np.int64)
    np.add.at(inter, (g_inv, p_inv), 1)
    gs = inter.sum(1)
    ps = inter.sum(0)
    union = gs[:, None] + ps[None, :] - inter
    iou = inter / np.maximum(union, 1)
    r, c = linear_sum_assignment(-iou)
    ok = iou[r, c] >= MATCH_IOU
    r, c = r[ok], c[ok]
    n_gt, n_pred, tp = len(gi), len(pi), len(r)
    iou_gt = np.zeros(n_gt)
    iou_gt[r] = iou[r, c]
    f1_gt = np.zeros(n_gt)
    f1_gt[r] = 2 * inter[r, c] / (gs[r] + ps[c])
    acc = inter[r, c].sum() / len(g)
    fp, fn = n_pred - tp, n_gt - tp
    pq = iou[r, c].sum() / (tp + 0.5 * fp + 0.5 * fn)
    return SegmentationScores(acc=100 * float(acc), miou=100 * float(iou_gt.mean()),
                              mf1=100 * float(f1_gt.mean()), pq=100 * float(pq),
                              n_gt=int(n_gt), n_pred=int(n_pred), tp=int(tp))
