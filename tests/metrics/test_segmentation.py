"""Segmentation metrics against hand-computed answers."""
import numpy as np
import pytest

from leaffit_usd.errors import ParameterError
from leaffit_usd.metrics import segmentation_scores

GT = np.array([0] * 10 + [1] * 10 + [2] * 10 + [-1] * 5)


def test_perfect_and_permuted_labels_score_100():
    for pred in (np.where(GT < 0, 0, GT), np.where(GT == 1, 2, np.where(GT == 2, 1, np.maximum(GT, 0)))):
        s = segmentation_scores(pred, GT)
        assert (s.acc, s.miou, s.mf1, s.pq) == (100, 100, 100, 100)
        assert (s.n_gt, s.n_pred, s.tp) == (3, 3, 3)


def test_floaters_are_excluded():
    pred = np.where(GT < 0, 7, np.maximum(GT, 0))  # floaters predicted as a leaf of their own
    s = segmentation_scores(pred, GT)
    assert s.acc == 100 and s.pq == 100 and s.n_pred == 3


def test_known_partial_answer():
    # leaf 2 loses 4 of its 10 Gaussians to the stem
    pred = np.maximum(GT, 0).copy()
    pred[20:24] = 0
    s = segmentation_scores(pred, GT)
    iou_stem, iou_1, iou_2 = 10 / 14, 1.0, 6 / 10
    f1_stem, f1_2 = 2 * 10 / (10 + 14), 2 * 6 / (10 + 6)
    assert s.acc == pytest.approx(100 * 26 / 30)
    assert s.miou == pytest.approx(100 * (iou_stem + iou_1 + iou_2) / 3)
    assert s.mf1 == pytest.approx(100 * (f1_stem + 1 + f1_2) / 3)
    assert s.pq == pytest.approx(100 * (iou_stem + iou_1 + iou_2) / 3)  # all matched: PQ = mIoU


def test_match_needs_iou_half_and_pq_counts_fp_fn():
    # leaf 2 split in two halves of IoU 0.5 and 0.3 -> only the 0.5 one may match
    pred = np.maximum(GT, 0).copy()
    pred[20:25] = 2
    pred[25:30] = 3
    gt = GT.copy()
    s = segmentation_scores(pred, gt)
    assert s.tp == 3 and s.n_pred == 4
    assert s.pq == pytest.approx(100 * (1 + 1 + 0.5) / (3 + 0.5 * 1 + 0))
    # merged leaves 1+2 into one prediction: IoU 0.5 each -> one matches, one is a miss
    pred = np.maximum(GT, 0).copy()
    pred[20:30] = 1
    s = segmentation_scores(pred, GT)
    assert s.tp == 2 and s.n_pred == 2
    assert s.miou == pytest.approx(100 * (1 + 0.5 + 0) / 3)
    assert s.acc == pytest.approx(100 * 20 / 30)
    assert s.pq == pytest.approx(100 * 1.5 / (2 + 0 + 0.5))
    # below 0.5: no match at all
    pred = np.maximum(GT, 0).copy()
    pred[10:30] = np.tile([1, 2, 3, 4, 5], 4)
    s = segmentation_scores(pred, GT)
    assert s.tp == 1  # only the stem


@pytest.mark.parametrize("pred,gt", [(np.zeros(3, int), np.zeros(4, int)),
                                     (np.zeros(3), np.zeros(3, int)),
                                     (np.zeros(3, int), -np.ones(3, int))])
def test_bad_inputs_rejected(pred, gt):
    with pytest.raises(ParameterError):
        segmentation_scores(pred, gt)
