"""The template leaf's Gaussians in its local frame (means, covariances, opacities) and their
view-dependent colours as the front and back textures see them."""
from __future__ import annotations

import numpy as np

from leaffit_usd.errors import ParameterError


def template_gaussians_local(cloud_working, fits, rotation=None):
    """(means (M, 3), cov (M, 3, 3), colors (M, 3), opacities (M,)) of the template's Gaussians in
    the template local frame (float64), or in the sheet-view frame when ``rotation`` (3, 3)
    (template -> view, :func:`leaffit_usd.mesh.view_frame.sheet_view_rotation`) is given."""
    row = template_row(fits)
    T = np.linalg.inv(np.asarray(fits.leaf_to_working[row], np.float64))
    if rotation is not None:
        T = np.vstack([np.asarray(rotation, np.float64) @ T[:3], T[3:]])
    idx = np.asarray(fits.template_gaussians, np.int64)
    idx = idx[(idx >= 0) & (idx < len(cloud_working))]
    g = cloud_working.subset(idx)
    A = T[:3, :3]
    means = g.means.astype(np.float64) @ A.T + T[:3, 3]
    cov = np.einsum("ij,njk,lk->nil", A, g.covariances().astype(np.float64), A)
    return means, cov, g.colors.astype(np.float64), g.opacities.astype(np.float64)


def template_view_colors(cloud_working, fits, rotation=None) -> dict[bool, np.ndarray]:
    """{from_below: (M, 3) float64 RGB in [0, 1]} of the template's Gaussians (the order of
    :func:`template_gaussians_local`) as the front (False: camera above the leaf, looking down its
    -Z) and back (True) textures see them: the SH, in the working frame, evaluated for the
    camera -> Gaussian direction of each view (the DC colour alone for SH degree 0)."""
    from leaffit_usd.splats.sh import eval_sh

    row = template_row(fits)
    leaf = np.asarray(fits.leaf_to_working[row], np.float64)[:3, :3]
    if rotation is not None:
        leaf = leaf @ np.asarray(rotation, np.float64).T   # view-frame directions -> working
    idx = np.asarray(fits.template_gaussians, np.int64)
    idx = idx[(idx >= 0) & (idx < len(cloud_working))]
    sh = cloud_working.sh[idx]
    out = {}
    for from_below, d_local in ((False, (0.0, 0.0, -1.0)), (True, (0.0, 0.0, 1.0))):
        d = leaf @ np.asarray(d_local)
        out[from_below] = np.clip(eval_sh(sh, d / np.linalg.norm(d)), 0.0, 1.0)
    return out


def template_row(fits) -> int:
    rows = np.flatnonzero(np.asarray(fits.leaf_labels) == fits.template_label)
    if len(rows) == 0:
        raise ParameterError("fits.leaf_labels", f"a row for the template leaf {fits.template_label}",
                             np.asarray(fits.leaf_labels).tolist())
    return int(rows[0])
