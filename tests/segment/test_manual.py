"""Geodesic drag and brush tools, label operations, undo/redo (synthetic two-leaf plant)."""
import numpy as np
import pytest

from leaffit_usd.errors import ParameterError, UserError
from leaffit_usd.segment.manual import ManualSegmenter, SampledGeodesics, compact_labels


@pytest.fixture(scope="module")
def geo(plant, heat):
    cloud = plant[0]
    return SampledGeodesics(cloud.means, height=1.0, n_samples=2000, solver_factory=heat)


def session(plant, geo, labels=None):
    cloud = plant[0]
    labels = np.zeros(len(cloud), np.int32) if labels is None else labels
    return ManualSegmenter(cloud.means, labels, 1.0, geodesics=geo)


def test_distances_are_geodesic_not_euclidean(plant, geo):
    cloud, truth, tips, bases = plant
    d = geo.distance(tips[0])
    assert d[tips[0]] < 0.01
    # tip to tip the path runs down one blade and up the other: about twice the blade's
    # centre-line arc length (+ the 0.04 gap), longer than the straight line between the tips
    u = np.linspace(0, 1, 2001)
    x, z = 0.45 * u, 0.25 * u + 0.05 * np.sin(np.pi * u)
    arc = 2 * np.hypot(np.diff(x), np.diff(z)).sum() + 0.04
    euclid = np.linalg.norm(cloud.means[tips[0]] - cloud.means[tips[1]])
    assert euclid < d[tips[1]] and abs(d[tips[1]] / arc - 1) < 0.15
    # monotone along the leaf: farther along the blade = larger distance
    leaf = np.flatnonzero(truth == 1)
    x = cloud.means[leaf, 0]
    assert np.corrcoef(-x, d[leaf])[0, 1] < -0.95
    # per-source caching returns the same field
    assert np.array_equal(d, geo.distance(tips[0]))


def test_drag_from_tip_to_base_selects_that_leaf(plant, geo):
    cloud, truth, tips, bases = plant
    seg = session(plant, geo)
    m = seg.drag_mask(tips[0], bases[0])
    d = geo.distance(tips[0])
    assert np.array_equal(m, d <= d[bases[0]])  # the paper's rule exactly
    assert (truth[m] == 1).mean() > 0.98  # precision
    assert m[truth == 1].mean() > 0.95  # recall
    # dragging only half way selects the outer half of the blade
    half = np.flatnonzero((truth == 1) & (np.abs(cloud.means[:, 0] + 0.25) < 0.01))[0]
    mh = seg.drag_mask(tips[0], half)
    assert 0.3 < mh[truth == 1].mean() < 0.75 and (truth[mh] == 1).all()


def test_brush_radius_add_and_erase(plant, geo):
    cloud, truth, tips, bases = plant
    seg = session(plant, geo)
    centre = int(np.flatnonzero((truth == 2) & (np.abs(cloud.means[:, 0] - 0.25) < 0.01))[0])
    small = seg.brush_mask([centre], 0.03)
    large = seg.brush_mask([centre], 0.1)
    assert small.sum() < large.sum() and not (small & ~large).any()
    assert (truth[large] == 2).all()
    d = geo.distance(centre)
    assert np.array_equal(large, d <= 0.1)
    seg.apply({"op": "brush", "centers": [centre], "radius": 0.1, "mode": "add"})
    assert np.array_equal(seg.selection, large)
    seg.apply({"op": "brush", "centers": [centre], "radius": 0.03, "mode": "erase"})
    assert np.array_equal(seg.selection, large & ~small)
    # a stroke is the union of its stamps, and the prefix cache does not change the result
    other = int(tips[1])
    stroke = seg.brush_mask([centre, other], 0.05)
    fresh = session(plant, geo).brush_mask([centre, other], 0.05)
    assert np.array_equal(stroke, fresh)
    assert np.array_equal(stroke, seg.brush_mask([centre], 0.05) | seg.brush_mask([other], 0.05))


def test_assign_new_existing_stem_and_leaf_operations(plant, geo):
    cloud, truth, tips, bases = plant
    seg = session(plant, geo)
    seg.apply({"op": "drag", "source": int(tips[0]), "target": int(bases[0])})
    seg.apply({"op": "assign", "label": "new"})
    assert seg.labels.max() == 1 and not seg.selection.any()
    seg.apply({"op": "drag", "source": int(tips[1]), "target": int(bases[1])})
    seg.apply({"op": "assign", "label": "new"})
    leaf1, leaf2 = seg.labels == 1, seg.labels == 2
    assert (truth[leaf1] == 1).mean() > 0.98 and (truth[leaf2] == 2).mean() > 0.98
    # assign to an existing leaf: the tip region of leaf 2 into leaf 1
    seg.apply({"op": "brush", "centers": [int(tips[1])], "radius": 0.05})
    moved = seg.selection.copy()
    seg.apply({"op": "assign", "label": 1})
    assert (seg.labels[moved] == 1).all()
    # to the stem
    seg.apply({"op": "select_leaf", "label": 1})
    seg.apply({"op": "brush", "centers": [int(tips[0])], "radius": 0.05, "mode": "erase"})
    sel = seg.selection.copy()
    assert sel.any() and (seg.labels[sel] == 1).all()
    seg.apply({"op": "assign", "label": 0})
    assert (seg.labels[sel] == 0).all()
    # split leaf 2 by a selection, merge, delete
    seg.apply({"op": "drag", "source": int(tips[1]), "target": int(np.flatnonzero((truth == 2) & (np.abs(cloud.means[:, 0] - 0.3) < 0.01))[0])})
    seg.apply({"op": "split", "label": 2})
    assert set(np.unique(seg.labels)) == {0, 1, 2, 3}
    seg.apply({"op": "merge", "labels": [2, 3]})
    assert set(np.unique(seg.labels)) == {0, 1, 2}
    seg.apply({"op": "delete", "label": 1})
    assert set(np.unique(seg.labels)) == {0, 2}
    assert np.array_equal(seg.final_labels(), (seg.labels == 2).astype(np.int32))


def test_undo_redo(plant, geo):
    plant_tips = plant[2]
    seg = session(plant, geo)
    seg.apply({"op": "brush", "centers": [int(plant_tips[0])], "radius": 0.1})
    s1 = seg.selection.copy()
    seg.apply({"op": "assign", "label": "new"})
    l2 = seg.labels.copy()
    assert seg.undo() and np.array_equal(seg.selection, s1) and seg.labels.max() == 0
    assert seg.undo() and not seg.selection.any() and not seg.can_undo and not seg.undo()
    assert seg.redo() and seg.redo() and not seg.redo()
    assert np.array_equal(seg.labels, l2) and len(seg.operations) == 2
    seg.undo()
    seg.apply({"op": "clear"})  # a new operation drops the redo stack
    assert not seg.can_redo and [o["op"] for o in seg.operations] == ["brush", "clear"]


@pytest.mark.parametrize("op, words", [
    ({"op": "paint"}, "unknown operation"),
    ({"op": "drag", "source": 0}, "target"),
    ({"op": "drag", "source": -1, "target": 3}, "source"),
    ({"op": "drag", "source": 0, "target": 10 ** 9}, "target"),
    ({"op": "brush", "centers": [], "radius": 0.1}, "centers"),
    ({"op": "brush", "centers": [1], "radius": -1}, "radius"),
    ({"op": "brush", "centers": [1], "radius": "big"}, "radius"),
    ({"op": "brush", "centers": [1], "radius": 0.1, "mode": "xor"}, "mode"),
    ({"op": "assign", "label": -2}, "label"),
    ({"op": "assign", "label": "leaf"}, "label"),
    ({"op": "merge", "labels": [1]}, "two"),
    ({"op": "delete", "label": 0}, "label"),
    ({"op": "split", "label": True}, "label"),
])
def test_bad_operations_are_refused(plant, geo, op, words):
    seg = session(plant, geo)
    with pytest.raises(UserError, match=words):
        seg.apply(op, op_no=7)
    assert seg.operations == []


def test_constructor_validation(plant, geo):
    cloud = plant[0]
    with pytest.raises(ParameterError):
        ManualSegmenter(cloud.means, np.zeros(3, np.int32), 1.0, geodesics=geo)
    with pytest.raises(ParameterError):
        ManualSegmenter(cloud.means, -np.ones(len(cloud), np.int32), 1.0, geodesics=geo)
    with pytest.raises(ParameterError):
        SampledGeodesics(cloud.means, height=0.0)
    with pytest.raises(ParameterError):
        geo.distance(len(cloud))
    with pytest.raises(ParameterError, match="normals"):
        SampledGeodesics(cloud.means, height=1.0, normals=np.zeros((3, 3)))


def test_compact_labels():
    assert compact_labels(np.array([0, 5, 5, 2, 0, 9])).tolist() == [0, 2, 2, 1, 0, 3]
    assert compact_labels(np.zeros(3, np.int32)).tolist() == [0, 0, 0]
