"""The texture bake evaluates view-dependent colour (SH) for each texture's own view direction."""
import numpy as np

from samples.synthetic.mesh import synthetic_leaf
from leaffit_usd.mesh.template import MeshParams, build_template_mesh
from leaffit_usd.splats.sh import SH_C1


def test_front_and_back_textures_see_their_own_view_dependent_colour():
    """Band-1 SH that add alpha * (d . n) to red, n the leaf's normal in the working frame and d
    the camera -> Gaussian direction: the front texture (camera above, d = -n) gets alpha less
    red, the back (d = +n) alpha more, against the same leaf baked with its DC colour only."""
    cloud, fits = synthetic_leaf(2500, seed=3)
    leaf = np.asarray(fits.leaf_to_working[0], np.float64)[:3, :3]
    n = leaf @ [0.0, 0.0, 1.0]
    n /= np.linalg.norm(n)
    alpha = 0.15
    sh = np.zeros((len(cloud), 4, 3), np.float32)
    sh[:, 0] = cloud.sh[:, 0]
    sh[:, 1:, 0] = np.array([-n[1], n[2], -n[0]]) * alpha / SH_C1  # basis: -C1 y, C1 z, -C1 x
    params = MeshParams(vertex_budget=500, texture_size=96)
    dc = build_template_mesh(cloud, fits, params)
    cloud.sh = sh
    vd = build_template_mesh(cloud, fits, params)
    for name, sign in (("front_texture", -1), ("back_texture", 1)):
        a, b = getattr(dc, name).astype(float), getattr(vd, name).astype(float)
        solid = (a[..., 3] > 250) & (b[..., 3] > 250)
        assert solid.mean() > 0.15  # the leaf covers about a quarter of the texture
        diff = (b - a)[solid][:, :3] / 255
        assert abs(np.median(diff[:, 0]) - sign * alpha) < 0.02, (name, np.median(diff[:, 0]))
        assert np.abs(np.median(diff[:, 1:], axis=0)).max() < 0.01  # green, blue unchanged
