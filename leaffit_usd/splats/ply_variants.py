"""The PLY layouts other trainers write beside the INRIA one, told apart by their vertex properties.

Kinds (the keys of ``formats.FORMAT_NAMES``), decided from the property names alone by
:func:`ply_kind`:

* ``ply``        INRIA 3DGS: ``x y z f_dc_0..2 [f_rest_*] opacity scale_0..2 rot_0..3``;
* ``ply_2dgs``   2D Gaussian Splatting (hbb1/2d-gaussian-splatting, ``save_ply``): the INRIA
  layout without ``scale_2``. A surfel is a flat disc: ``scale_0``, ``scale_1`` (log) span it, and
  its normal is the rotation's third column (local z). PlayCanvas splat-transform reads such a
  file the same way and fills the missing scale with ``-Infinity`` (linear 0). We keep every
  Gaussian finite instead (a zero scale makes the covariance singular and ``drop_invalid`` would
  drop the lot): ``scale_2 = SURFEL_THICKNESS x min(scale_0, scale_1)`` in linear units, i.e.
  ``log_scale_2 = min(log_scale_0, log_scale_1) + log(SURFEL_THICKNESS)``. The third axis is then
  always the shortest, so :meth:`GaussianCloud.shortest_axes` returns the surfel normal;
* ``ply_gof``    Gaussian Opacity Fields (autonomousvision/gaussian-opacity-fields; Mip-Splatting
  writes the same): the INRIA layout plus ``filter_3D``, a per-Gaussian 3D low-pass filter, a
  linear standard deviation in input units. GOF renders every Gaussian through it
  (``GaussianModel.get_scaling_with_3D_filter`` / ``get_opacity_with_3D_filter``), and so do we,
  once, at load (:func:`apply_3d_filter`); ``filter_3D`` is then dropped from ``extra`` (written
  back it would be applied twice);
* ``ply_points`` a plain point cloud: ``x y z`` with none of ``opacity``, ``scale_*``, ``rot_*``
  (colour and any other property optional) -> :mod:`leaffit_usd.splats.scans`.
"""
from __future__ import annotations

import numpy as np

SURFEL_THICKNESS = 0.01  # a 2DGS surfel's third scale, x its smaller in-plane scale
_GAUSSIAN_PROPS = ("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")


def ply_kind(names) -> str:
    """``ply``, ``ply_2dgs``, ``ply_gof`` or ``ply_points`` for a PLY's vertex property names.

    A layout that matches none exactly (a 3DGS file missing some property) is ``ply``, so the
    INRIA reader names what is missing.
    """
    names = set(names)
    if {"x", "y", "z"} <= names and not names & set(_GAUSSIAN_PROPS) and "f_dc_0" not in names:
        return "ply_points"
    if "scale_2" not in names and {"scale_0", "scale_1"} <= names:
        return "ply_2dgs"
    if "filter_3D" in names:
        return "ply_gof"
    return "ply"


def surfel_third_scale(log_scales: np.ndarray) -> np.ndarray:
    """(N,) float32: the thin third log-scale of 2DGS surfels (rule in the module doc).

    log_scales : (N, 2) float, natural logs of the surfel's two in-plane standard deviations.
    """
    ls = np.asarray(log_scales, np.float64)
    return (ls.min(axis=1) + np.log(SURFEL_THICKNESS)).astype(np.float32)


def apply_3d_filter(log_scales: np.ndarray, opacity_logits: np.ndarray,
                    filter_3d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """GOF's 3D filter baked into the Gaussians: ``(log_scales (N, 3), opacity_logits (N,))`` float32.

    log_scales : (N, 3) float, log standard deviations; opacity_logits : (N,) float;
    filter_3d : (N,) float, the filter's standard deviation (linear, input units).
    As GOF: ``s' = sqrt(s^2 + f^2)`` per axis and ``opacity' = opacity * sqrt(prod(s^2) /
    prod(s^2 + f^2))`` (the filtered Gaussian keeps the original's integral), computed in float64.
    """
    s2 = np.exp(2.0 * np.asarray(log_scales, np.float64))
    f2 = np.square(np.asarray(filter_3d, np.float64))[:, None]
    after = s2 + f2
    coef = np.sqrt(np.prod(s2 / after, axis=1))
    op = coef / (1.0 + np.exp(-np.asarray(opacity_logits, np.float64)))
    op = np.clip(op, 1e-7, 1.0 - 1e-7)
    return (0.5 * np.log(after)).astype(np.float32), np.log(op / (1.0 - op)).astype(np.float32)
