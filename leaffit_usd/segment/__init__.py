"""Leaf instance segmentation (heat geodesics) and manual tools."""
from leaffit_usd.segment.result import Segmentation

__all__ = ["Segmentation"]
