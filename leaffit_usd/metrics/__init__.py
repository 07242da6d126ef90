"""Evaluation metrics (segmentation; deformation lives in metrics/deformation.py)."""
from leaffit_usd.metrics.segmentation import MATCH_IOU, SegmentationScores, segmentation_scores

__all__ = ["MATCH_IOU", "SegmentationScores", "segmentation_scores"]
