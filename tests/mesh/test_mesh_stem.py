"""Stem cylinders and Leonardo's rule (leaffit_usd.mesh.stem)."""
import logging

import numpy as np
import pytest

from leaffit_usd.errors import ParameterError
from leaffit_usd.mesh import surface as S
from leaffit_usd.mesh.stem import StemParams, build_stem, estimate_radii, stem_edges
from leaffit_usd.segment.result import Segmentation

R_ROOT, R_PET = 0.012, 0.003


@pytest.fixture(scope="module")
def stem(tree):
    seg, pts = tree
    return build_stem(seg, pts, None, StemParams(root_radius=R_ROOT, petiole_radius=R_PET))


def test_edges_exclude_leaf_interiors(tree, stem):
    seg, _ = tree
    child, parent = stem_edges(seg)
    lab = seg.tree_leaf
    assert not ((lab[child] != 0) & (lab[child] == lab[parent])).any()
    # every leaf is attached: one stem edge ends at each leaf's first node
    assert sorted(set(lab[child][lab[child] > 0].tolist())) == list(range(1, seg.n_leaves + 1))
    full = build_stem(seg, tree[1], None, StemParams(root_radius=R_ROOT, petiole_radius=R_PET, simplify=0))
    assert len(full.starts) == len(child)
    # the default simplification merges straight runs but keeps every junction and tip
    assert len(stem.starts) < len(child)
    ends = lambda st: {tuple(np.round(p, 6)) for p in st.ends[np.setdiff1d(np.arange(len(st.ends)), st.parent)]}
    assert ends(stem) == ends(full)


def test_leonardo_rule_at_every_junction(stem):
    junctions = 0
    for e in range(len(stem.starts)):
        kids = np.flatnonzero(stem.parent == e)
        if len(kids) == 0:
            continue
        # children start where the parent ends
        assert np.allclose(stem.starts[kids], stem.ends[e])
        parent_area = np.pi * stem.radii_end[e] ** 2
        child_area = np.pi * (stem.radii_start[kids] ** 2).sum()
        assert parent_area == pytest.approx(child_area, rel=1e-5)
        junctions += len(kids) > 1
    # roots: several cylinders starting at the root also obey the rule against the root radius
    roots = np.flatnonzero(stem.parent == -1)
    assert np.pi * R_ROOT ** 2 == pytest.approx(np.pi * (stem.radii_start[roots] ** 2).sum(), rel=1e-5)
    assert junctions >= 3


def test_radii_from_root_to_petioles(stem):
    roots = np.flatnonzero(stem.parent == -1)
    assert stem.radii_start[roots].max() <= R_ROOT * (1 + 1e-6)
    tips = np.setdiff1d(np.arange(len(stem.starts)), stem.parent)
    assert np.allclose(stem.radii_end[tips], R_PET, rtol=1e-5)
    # radii never grow from root to tips (r_root >= r_pet * sqrt(n_leaves) here)
    assert (stem.radii_end <= stem.radii_start + 1e-7).all()
    has_parent = stem.parent >= 0
    assert (stem.radii_start[has_parent] <= stem.radii_end[stem.parent[has_parent]] + 1e-7).all()


def test_joints_are_closed(stem):
    """Every open tube end is capped by a joint sphere at least as wide (no gaps at joints)."""
    import trimesh

    tm = trimesh.Trimesh(stem.points, stem.faces, process=False)
    bodies = tm.split(only_watertight=False)
    spheres = [(b.vertices.mean(0), np.linalg.norm(b.vertices - b.vertices.mean(0), axis=1).min())
               for b in bodies if b.is_watertight]
    centres = np.array([c for c, _ in spheres])
    radii = np.array([r for _, r in spheres])
    loops = S.boundary_loops(stem.faces.astype(np.int64), len(stem.points))
    assert loops
    for lp in loops:
        ring = stem.points[lp].astype(float)
        c = ring.mean(0)
        r = np.linalg.norm(ring - c, axis=1).max()
        d = np.linalg.norm(centres - c, axis=1)
        k = int(np.argmin(d))
        assert d[k] < 1e-4, "tube end without a joint sphere"
        # the sphere's inscribed radius (polyhedron) covers the ring: scale by cos(pi/sides)
        assert radii[k] >= r * np.cos(np.pi / 8) * np.cos(np.pi / 8) - 1e-6


def test_mesh_follows_tree(tree, stem):
    seg, pts = tree
    # every mesh vertex lies within a few radii of some cylinder axis
    from scipy.spatial import cKDTree

    axis = np.concatenate([np.linspace(a, b, 10) for a, b in zip(stem.starts, stem.ends)])
    d, _ = cKDTree(axis).query(stem.points)
    assert d.max() < 3 * R_ROOT


def test_default_radii_from_capture(tree):
    seg, pts = tree  # stem Gaussians of radius 0.01 around the lower main stem
    root_r, _ = estimate_radii(seg, pts)
    assert root_r == pytest.approx(0.01, rel=0.15)
    st = build_stem(seg, pts)
    assert st.radii_start[st.parent == -1].max() == pytest.approx(root_r, rel=1e-5)


def _seg(parent, leaf):
    n = len(parent)
    return Segmentation(labels=np.asarray(leaf, np.int32), root_index=0,
                        tree_nodes=np.arange(n), tree_parent=np.asarray(parent),
                        tree_leaf=np.asarray(leaf, np.int32))


def test_single_edge_tree_warns(caplog):
    seg = _seg([-1, 0], [0, 0])
    pts = np.array([[0, 0, 0], [0, 0, 0.2]], float)
    with caplog.at_level(logging.WARNING, logger="leaffit_usd"):
        st = build_stem(seg, pts, None, StemParams(root_radius=0.01, petiole_radius=0.004))
    assert len(st.starts) == 1 and len(st.faces) > 0
    assert st.radii_start[0] == pytest.approx(0.01) and st.radii_end[0] == pytest.approx(0.004)
    assert "single stem edge" in caplog.text


def test_no_stem_edges_warns(caplog):
    with caplog.at_level(logging.WARNING, logger="leaffit_usd"):
        st = build_stem(_seg([-1], [0]), np.zeros((1, 3)))
        st2 = build_stem(_seg([], []), np.zeros((0, 3)))
    assert len(st.starts) == 0 and len(st2.faces) == 0
    assert "no stem edges" in caplog.text


@pytest.mark.parametrize("bad", [dict(root_radius=-1.0), dict(petiole_radius=0.0), dict(sides=2),
                                 dict(sphere_rings=1), dict(root_radius=float("nan"))])
def test_params_validation(tree, bad):
    seg, pts = tree
    with pytest.raises(ParameterError):
        build_stem(seg, pts, None, StemParams(**bad))


def test_bad_tree_indices(tree):
    seg, pts = tree
    with pytest.raises(ParameterError):
        build_stem(seg, pts[:5])
