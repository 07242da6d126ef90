"""The two-leaf plant and the geodesic solver shared by the manual-segmentation tests."""
from tests.segment.two_leaf import heat, plant  # noqa: F401  (fixtures)
