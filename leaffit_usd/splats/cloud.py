"""The GaussianCloud value: one 3DGS capture, in the parameterisation the INRIA PLY stores.

Conventions (owned here, used everywhere):

* quaternions are (w, x, y, z), real part first, as ``rot_0..3`` in the INRIA PLY;
* scales are stored as natural logs (``scale_0..2``), opacity as a logit (``opacity``);
  :attr:`GaussianCloud.scales`, :attr:`GaussianCloud.opacities` and
  :attr:`GaussianCloud.rotations` give the activated values;
* SH coefficients are ``sh[:, k, c]``: basis function ``k`` (0 = DC), colour channel ``c``;
  the PLY stores ``f_rest`` channel-major (all R coefficients, then G, then B);
* the order of Gaussians is their identity. Gaussians dropped at load (NaN, zero quaternion)
  are remembered through :attr:`file_index`, so per-Gaussian results (labels) can always be
  written back in file order with :meth:`GaussianCloud.to_file_order`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from leaffit_usd.geometry.quaternion import quat_to_matrix

log = logging.getLogger("leaffit_usd")

SH_C0 = 0.28209479177387814  # Y_0^0; colour = SH_C0 * f_dc + 0.5
REST_COUNTS = {0: 0, 1: 9, 2: 24, 3: 45}  # SH degree -> number of f_rest_* properties


@dataclass
class GaussianCloud:
    """A set of N 3D Gaussians, input frame.

    means : (N, 3) float32, input frame
    log_scales : (N, 3) float32, natural log of the standard deviations, input units
    quats : (N, 4) float32, (w, x, y, z) as stored (not necessarily unit length, never zero)
    opacity_logits : (N,) float32
    sh : (N, C, 3) float32, C = (degree + 1)**2; sh[:, 0] is the DC term
    extra : per-Gaussian properties kept verbatim (name -> (N,) array, original dtype), e.g.
        ``nx, ny, nz`` or a trainer's own fields; written back in this order
    file_index : (N,) int64, position of each Gaussian in the file it was read from
    file_count : number of Gaussians in that file (>= N)
    """

    means: np.ndarray
    log_scales: np.ndarray
    quats: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    file_index: np.ndarray | None = None
    file_count: int | None = None

    def __post_init__(self) -> None:
        n = len(self.means)
        if self.file_index is None:
            self.file_index = np.arange(n, dtype=np.int64)
        if self.file_count is None:
            self.file_count = n

    # ---- sizes -------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.means)

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.sh.shape[1]))) - 1

    @property
    def nbytes(self) -> int:
        arrays = [self.means, self.log_scales, self.quats, self.opacity_logits, self.sh,
                  self.file_index, *self.extra.values()]
        return int(sum(a.nbytes for a in arrays))

    # ---- activated values ---------------------------------------------------------------
    @property
    def scales(self) -> np.ndarray:
        """(N, 3) float32, standard deviations along the Gaussian's local axes, input units."""
        return np.exp(self.log_scales)

    @property
    def opacities(self) -> np.ndarray:
        """(N,) float32 in (0, 1)."""
        return (1.0 / (1.0 + np.exp(-self.opacity_logits.astype(np.float64)))).astype(np.float32)

    @property
    def rotations(self) -> np.ndarray:
        """(N, 4) float32 unit quaternions (w, x, y, z)."""
        q = self.quats.astype(np.float64)
        return (q / np.linalg.norm(q, axis=1, keepdims=True)).astype(np.float32)

    @property
    def colors(self) -> np.ndarray:
        """(N, 3) float32 view-independent RGB in [0, 1] (DC term only)."""
        return np.clip(SH_C0 * self.sh[:, 0, :] + 0.5, 0.0, 1.0).astype(np.float32)

    def rotation_matrices(self) -> np.ndarray:
        """(N, 3, 3) float32; columns are the Gaussian's local axes in the input frame."""
        return quat_to_matrix(self.rotations)

    def shortest_axes(self) -> np.ndarray:
        """(N, 3) float32, input frame: each Gaussian's shortest axis (its surface normal when flat)."""
        r = self.rotation_matrices()
        k = np.argmin(self.log_scales, axis=1)
        return np.ascontiguousarray(r[np.arange(len(self)), :, k])

    def covariances(self) -> np.ndarray:
        """(N, 3, 3) float32 covariance matrices, input frame: R diag(s^2) R^T."""
        r = self.rotation_matrices()
        s2 = self.scales ** 2
        return np.einsum("nij,nj,nkj->nik", r, s2, r).astype(np.float32)

    # ---- selection and file order -------------------------------------------------------
    def subset(self, index) -> "GaussianCloud":
        """A new cloud with the Gaussians ``index`` (bool mask or integer indices)."""
        return GaussianCloud(
            means=self.means[index], log_scales=self.log_scales[index], quats=self.quats[index],
            opacity_logits=self.opacity_logits[index], sh=self.sh[index],
            extra={k: v[index] for k, v in self.extra.items()},
            file_index=self.file_index[index], file_count=self.file_count,
        )

    def to_file_order(self, values: np.ndarray, fill=0) -> np.ndarray:
        """Scatter per-Gaussian ``values`` (N, ...) to the file's order (file_count, ...).

        Gaussians dropped at load get ``fill``.
        """
        values = np.asarray(values)
        out = np.full((self.file_count, *values.shape[1:]), fill, dtype=values.dtype)
        out[self.file_index] = values
        return out

    @staticmethod
    def from_activated(means, scales, rotations, opacities, colors=None, sh=None,
                       extra=None) -> "GaussianCloud":
        """Build a cloud from activated values (linear scales, opacities in (0,1), RGB colours).

        means, scales : (N, 3); rotations : (N, 4) (w, x, y, z); opacities : (N,);
        colors : (N, 3) RGB in [0, 1] (DC only) or sh : (N, C, 3).
        """
        n = len(means)
        op = np.clip(np.asarray(opacities, np.float64), 1e-6, 1 - 1e-6)
        if sh is None:
            c = np.zeros((n, 3)) if colors is None else np.asarray(colors, np.float64)
            sh = ((c - 0.5) / SH_C0)[:, None, :]
        return GaussianCloud(
            means=np.ascontiguousarray(means, np.float32),
            log_scales=np.log(np.maximum(np.asarray(scales, np.float64), 1e-12)).astype(np.float32),
            quats=np.ascontiguousarray(rotations, np.float32),
            opacity_logits=np.log(op / (1 - op)).astype(np.float32),
            sh=np.ascontiguousarray(sh, np.float32),
            extra=dict(extra or {}),
        )


def drop_invalid(cloud: GaussianCloud, source: str, max_fraction: float = 0.5) -> GaussianCloud:
    """Remove Gaussians with NaN/Inf values or a zero quaternion, with a warning saying how many.

    Raises ``InputFileError`` when the cloud is empty or more than ``max_fraction`` of it is
    invalid (that is a broken file, not a few oddities).
    """
    from leaffit_usd.errors import InputFileError

    n = len(cloud)
    if n == 0:
        raise InputFileError(source, "contains no Gaussians")
    finite = np.isfinite(cloud.means).all(1) & np.isfinite(cloud.log_scales).all(1)
    finite &= np.isfinite(cloud.quats).all(1) & np.isfinite(cloud.opacity_logits)
    finite &= np.isfinite(cloud.sh).all((1, 2))
    nonzero_q = np.einsum("ij,ij->i", cloud.quats.astype(np.float64), cloud.quats) > 1e-20
    ok = finite & nonzero_q
    bad = n - int(ok.sum())
    if bad == 0:
        return cloud
    if bad > max_fraction * n:
        what = []
        if (~finite).any():
            what.append(f"{int((~finite).sum())} with NaN/Inf values")
        if (~nonzero_q).any():
            what.append(f"{int((~nonzero_q).sum())} with a zero-length quaternion")
        raise InputFileError(source, f"{bad} of {n} Gaussians are invalid ({', '.join(what)})")
    log.warning("%s: dropped %d of %d Gaussians (%d non-finite, %d zero quaternion)",
                source, bad, n, int((~finite).sum()), int((finite & ~nonzero_q).sum()))
    return cloud.subset(ok)
