"""geometry.normals: face and area-weighted vertex normals, batches, degenerate vertices."""
import numpy as np

from leaffit_usd.geometry.normals import face_normals, vertex_normals

SQUARE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [5, 5, 5]], float)  # + unused vertex
FACES = np.array([[0, 1, 2], [0, 2, 3]])


def test_face_normals_are_twice_the_area():
    fn = face_normals(SQUARE, FACES)
    np.testing.assert_allclose(fn, [[0, 0, 1], [0, 0, 1]])


def test_vertex_normals_and_undefined_vertices():
    n = vertex_normals(SQUARE, FACES)
    np.testing.assert_allclose(n[:4], np.tile([0, 0, 1.0], (4, 1)))
    assert np.array_equal(n[4], [0, 0, 0])  # used by no face
    n = vertex_normals(SQUARE, FACES, undefined=(0, 0, 1))
    assert np.array_equal(n[4], [0, 0, 1])
    np.testing.assert_allclose(vertex_normals(SQUARE, FACES[:, ::-1])[:4], np.tile([0, 0, -1.0], (4, 1)))
    assert np.array_equal(vertex_normals(SQUARE, np.zeros((0, 3), int)), np.zeros((5, 3)))


def test_area_weighting_and_batches():
    # a tent: two faces of different area meeting along the x axis
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 1], [0, -3, 3]], float)
    f = np.array([[0, 1, 2], [1, 0, 3]])
    n = vertex_normals(v, f)
    want = face_normals(v, f).sum(0)
    np.testing.assert_allclose(n[0], want / np.linalg.norm(want))
    rng = np.random.default_rng(0)
    batch = rng.normal(size=(3, 4, 3))
    nb = vertex_normals(batch, f)
    assert nb.shape == (3, 4, 3)
    for i in range(3):
        np.testing.assert_allclose(nb[i], vertex_normals(batch[i], f))
