"""Template leaf mesh: surface, two-sided UVs and texture bake (paper, "Template Leaf Mesh Extraction").

Pipeline (template local frame: petiole base at the origin, +X base -> apex, +Z leaf normal):

1. **Samples** — farthest point sampling of the template's denoised Gaussian centres
   (``fits.template_points``) down to ``vertex_budget`` (2,048, the paper's). Hole filling adds
   no vertices, so the sheet has at most that many vertices (fewer when BPA leaves samples out).
   The budget counts the *sheet's* vertices (geometric positions); the two-sided mesh duplicates
   each per side, so ``TemplateMesh.points`` has twice as many rows.
2. **Surface** — ball pivoting + repair (the paper's), or the planar fallback, see
   :mod:`leaffit_usd.mesh.surface`. ``method="auto"`` runs BPA and falls back to planar when the
   repaired BPA sheet fails the disk/thin checks, with a warning.
3. **UVs** — planar, from the template frame's xy (the PCA-aligned view the fit uses). Chosen
   over xatlas because the bake is an orthographic render along +-Z of that very frame: with
   planar UVs a texel *is* a render pixel (no resampling through the surface, no seams, one
   island per side, front and back registered), and the texture reads as a picture of the leaf,
   which the retexture tool and artists edit directly. The cost: stretch where the leaf's
   surface is steep in this view (strongly curled leaves); the report gives ``uv_stretch_max``
   (largest 3D/2D edge length ratio). Texels are square; the leaf's larger xy extent (plus a
   margin) spans the image.
4. **Two sides** — every sheet vertex and triangle is duplicated: front copy (CCW seen from +Z,
   normals +Z-ish, ``uv = (u, v)`` into ``front_texture``) then back copy (reversed winding,
   negated normals, ``uv = (1 - u, v)`` into ``back_texture``: the back texture is the leaf as
   seen from behind, not mirrored).
5. **Bake** — the template's Gaussians (``cloud_working.subset(fits.template_gaussians)``,
   mapped into the template frame by ``inverse(fits.leaf_to_working[template row])``) are
   rendered with THE splat renderer (:mod:`leaffit_usd.splats.render`) from +Z (front) and from
   -Z (back). Each side is its own layer of Gaussians (those on its side of the sheet: signed
   offset along the closest face's normal) composited *over* the other layer: the rasteriser
   sorts Gaussians globally by centre depth, which would mix a blade's two thin layers wherever
   the blade is tilted in the view; gaps in a layer show the other one. Colour is
   un-premultiplied; alpha is 1 where the splat coverage exceeds ``alpha_threshold`` (interior
   pin-holes closed) with a one-texel anti-aliased rim, so the cut-out follows the leaf's own
   silhouette; colours are then dilated outwards over the whole image (nearest covered texel) so
   mip-maps never bleed background into the leaf. DC colours only: the cloud's SH rest
   coefficients are not rotated into the working frame.

Fallbacks (each with a warning): a side with few Gaussians of its own (a leaf seen from one side
only) shows the other layer — reported as ``one_layer_sides``; a side still covering less than
``min_coverage`` of the sheet's silhouette takes the other side's texture; when both are poor (a
sparse capture) colours are inpainted over the sheet and alpha = the sheet.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.geometry.normals import vertex_normals
from leaffit_usd.image_io import write_image
from leaffit_usd.geometry.sampling import farthest_point_sampling
from leaffit_usd.mesh import surface as surf
from leaffit_usd.mesh.result import TemplateLOD, TemplateMesh

log = logging.getLogger("leaffit_usd")

METHODS = ("auto", "bpa", "planar")
FORMATS = ("png", "exr")  # write_textures: lossless (8-bit sRGB or half-float linear)
MAX_OFF_SHEET_FRACTION = 0.02  # samples farther than one spacing from the sheet (rim left out)


@dataclass
class MeshParams:
    """Template mesh parameters.

    vertex_budget : maximum number of sheet vertices (FPS samples), paper: 2,048
    texture_size : width = height of each side's baked texture in pixels (``convert --bake-size``;
        the stage's files may be downsampled when written: ``WriteOptions.texture_max_size``)
    method : "auto" (BPA, planar fallback), "bpa" (BPA only; still falls back when it produces
        nothing usable) or "planar"
    bpa_radii : ball radii, multiples of the samples' median nearest-neighbour spacing
    alpha : planar method's alpha-shape circumradius, multiple of the same spacing
    texture_margin : empty border around the leaf in the texture, fraction of its extent
    uv_layout : "fit" (the chart's bounding box fills the square texture: texels follow the
        leaf's aspect ratio) or "square" (square texels, the leaf's larger extent spans it)
    supersample : the bake renders at this many times the texture size per axis and
        box-filters down (premultiplied), then divides by the accumulated alpha
    clean_outline : re-triangulate the sheet inside a smooth outline curve (constrained
        Delaunay, :func:`surface.remesh_sheet`); the fine serration stays in the alpha cut-out
    lod_vertices : vertex budgets of the coarser levels of detail (per side)
    alpha_threshold : splat coverage at which the cut-out edge lies
    min_coverage : smallest fraction of the sheet's silhouette a side's splats must cover
    """

    vertex_budget: int = 2048
    texture_size: int = 1024
    method: str = "auto"
    bpa_radii: tuple = (2.0, 3.0, 4.0)
    alpha: float = 2.5
    texture_margin: float = 0.01
    uv_layout: str = "fit"
    supersample: int = 2
    clean_outline: bool = True
    lod_vertices: tuple = (512, 128)
    alpha_threshold: float = 0.5
    min_coverage: float = 0.6

    def validate(self) -> None:
        if not isinstance(self.vertex_budget, (int, np.integer)) or self.vertex_budget < 3:
            raise ParameterError("vertex_budget", "an integer >= 3", self.vertex_budget)
        if not isinstance(self.texture_size, (int, np.integer)) or not 8 <= self.texture_size <= 16384:
            raise ParameterError("texture_size", "an integer in [8, 16384]", self.texture_size)
        if self.method not in METHODS:
            raise ParameterError("method", ", ".join(METHODS), self.method)
        radii = tuple(self.bpa_radii)
        if not radii or not all(np.isfinite(r) and r > 0 for r in radii):
            raise ParameterError("bpa_radii", "positive multiples of the sample spacing", self.bpa_radii)
        if self.uv_layout not in ("fit", "square"):
            raise ParameterError("uv_layout", "fit or square", self.uv_layout)
        if not isinstance(self.supersample, (int, np.integer)) or not 1 <= self.supersample <= 4:
            raise ParameterError("supersample", "an integer in 1..4", self.supersample)
        if not all(isinstance(n, (int, np.integer)) and n >= 8 for n in tuple(self.lod_vertices)):
            raise ParameterError("lod_vertices", "integers >= 8", self.lod_vertices)
        for name, lo, hi in (("alpha", 0.5, 100.0), ("texture_margin", 0.0, 0.45),
                             ("alpha_threshold", 0.01, 0.99), ("min_coverage", 0.0, 1.0)):
            v = getattr(self, name)
            if not (np.isfinite(v) and lo <= v <= hi):
                raise ParameterError(name, f"a number in [{lo}, {hi}]", v)


# ---- surface ----------------------------------------------------------------------------------
def _off_sheet_fraction(samples: np.ndarray, sheet: surf.Sheet, spacing: float) -> float:
    if len(sheet.faces) == 0:
        return 1.0
    d = point_sheet_distance(samples, sheet.points, sheet.faces)
    return float(np.mean(d > spacing))


def point_sheet_distance(points: np.ndarray, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(M,) float64 distance of each point to the triangle mesh (open3d raycasting scene)."""
    import open3d as o3d

    if len(points) == 0:
        return np.zeros(0)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(verts, np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)))
    q = o3d.core.Tensor(np.ascontiguousarray(points, np.float32))
    return scene.compute_distance(q).numpy().astype(np.float64)


def build_sheet(samples: np.ndarray, params: MeshParams) -> tuple[surf.Sheet, dict]:
    """The single-sheet surface of ``samples`` (S, 3) float, template local frame.

    Returns the sheet and its check figures; falls back (BPA -> planar -> a quad) with a
    warning, never raises for degenerate input.
    """
    tried = []
    best = None
    spacing = surf.sample_spacing(samples) if len(samples) >= 2 else 1.0
    order = {"auto": ("bpa", "planar"), "bpa": ("bpa", "planar"), "planar": ("planar",)}[params.method]
    for method in order:
        if len(samples) < 4:
            tried.append(f"{method}: only {len(samples)} points")
            continue
        try:
            if method == "bpa":
                sheet = surf.bpa_sheet(samples, params.bpa_radii)
            else:
                sheet = surf.planar_sheet(samples, params.alpha)
        except Exception as exc:  # a library failing on odd input must not stop the pipeline
            tried.append(f"{method}: {type(exc).__name__}: {exc}")
            continue
        checks = surf.sheet_checks(sheet.points, sheet.faces)
        off = _off_sheet_fraction(samples, sheet, spacing)
        checks["off_sheet_fraction"] = off
        problems = []
        if not checks["is_disk"]:
            problems.append(f"not a single disk ({checks['components']} components, "
                            f"{checks['boundary_loops']} boundary loops, "
                            f"{checks['nonmanifold_edges']} non-manifold edges, "
                            f"{checks['nonmanifold_vertices']} non-manifold vertices, "
                            f"fold ratio {checks['fold_ratio']:.3f})")
        if off > MAX_OFF_SHEET_FRACTION:
            problems.append(f"{100 * off:.1f}% of the samples lie off the sheet")
        if not problems:
            if tried:
                log.warning("mesh: template surface fell back to %s (%s)", method, "; ".join(tried))
            checks["fallback_reasons"] = tried
            return sheet, checks
        tried.append(f"{method}: " + ", ".join(problems))
        if len(sheet.faces) and (best is None or (not best[1]["is_disk"] and checks["is_disk"])):
            best = (sheet, checks)
    if best is not None:  # nothing passed every check: keep the best surface there is
        log.warning("mesh: template surface is not a clean disk (%s); keeping the %s result",
                    "; ".join(tried), best[0].info.get("method"))
        best[1]["fallback_reasons"] = tried
        return best
    log.warning("mesh: no surface could be built from %d template points (%s); using a quad",
                len(samples), "; ".join(tried))
    sheet = surf.fallback_quad(samples)
    checks = surf.sheet_checks(sheet.points, sheet.faces)
    checks["off_sheet_fraction"] = 0.0
    checks["fallback_reasons"] = tried
    return sheet, checks


# ---- UVs and rasterising ---------------------------------------------------------------------------
def uv_bounds(xy: np.ndarray, size: int, margin: float) -> tuple[float, float, float, float]:
    """Square-texel bounds (xmin, xmax, ymin, ymax) of a ``size`` x ``size`` texture around ``xy``."""
    from leaffit_usd.splats.render import fit_bounds

    return fit_bounds(xy, size, size, margin)


def chart_bounds(xy: np.ndarray, margin: float, size: int = 0) -> tuple[float, float, float, float]:
    """Aspect-fitted bounds (xmin, xmax, ymin, ymax): the bounding box of ``xy`` (S, 2) grown by
    ``margin`` of its own extent on each axis; mapped onto the whole square texture, so the
    leaf fills it whatever its aspect ratio (texels are then rectangles on the leaf). With
    ``size`` (texels), the margin is at least 5 texels (the cut-out's soft rim stays off the
    border: an empty border for clamped lookups)."""
    if size:
        margin = max(margin, 5.0 / size)
    m = np.asarray(xy, np.float64)[:, :2]
    if len(m) == 0:
        return (-1.0, 1.0, -1.0, 1.0)
    lo, hi = m.min(0), m.max(0)
    ext = np.maximum(hi - lo, 1e-9)
    lo, hi = lo - margin * ext, hi + margin * ext
    return (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))


def planar_uvs(xy: np.ndarray, bounds) -> np.ndarray:
    """(S, 2) front UVs of template-frame ``xy`` (S, 2) for the texture covering ``bounds``."""
    xmin, xmax, ymin, ymax = bounds
    return np.stack([(xy[:, 0] - xmin) / (xmax - xmin), (xy[:, 1] - ymin) / (ymax - ymin)], 1)


def rasterize_polygon(poly_xy: np.ndarray, width: int, height: int, bounds) -> np.ndarray:
    """(H, W) bool: pixel centres inside the closed polygon (k, 2) (even-odd rule), image layout
    of the renderer (row 0 = ymax)."""
    xmin, xmax, ymin, ymax = bounds
    sx, sy = (xmax - xmin) / width, (ymax - ymin) / height
    yc = ymax - (np.arange(height) + 0.5) * sy                        # (H,)
    p0, p1 = poly_xy, np.roll(poly_xy, -1, 0)
    y0, y1 = p0[:, 1][None], p1[:, 1][None]
    cross = ((y0 <= yc[:, None]) & (yc[:, None] < y1)) | ((y1 <= yc[:, None]) & (yc[:, None] < y0))
    t = (yc[:, None] - y0) / np.where(y1 != y0, y1 - y0, 1.0)
    xc = p0[:, 0][None] + t * (p1[:, 0] - p0[:, 0])[None]
    col = np.ceil((xc - xmin) / sx - 0.5).astype(np.int64)            # first pixel right of x
    col = np.clip(col, 0, width)
    r, e = np.nonzero(cross)
    toggle = np.zeros((height, width + 1), np.int64)
    np.add.at(toggle, (r, col[r, e]), 1)
    return (np.cumsum(toggle, axis=1)[:, :width] % 2).astype(bool)


# ---- bake -----------------------------------------------------------------------------------------
def template_gaussians_local(cloud_working, fits):
    """(means (M, 3), cov (M, 3, 3), colors (M, 3), opacities (M,)) of the template's Gaussians in
    the template local frame (float64)."""
    row = _template_row(fits)
    T = np.linalg.inv(np.asarray(fits.leaf_to_working[row], np.float64))
    idx = np.asarray(fits.template_gaussians, np.int64)
    idx = idx[(idx >= 0) & (idx < len(cloud_working))]
    g = cloud_working.subset(idx)
    A = T[:3, :3]
    means = g.means.astype(np.float64) @ A.T + T[:3, 3]
    cov = np.einsum("ij,njk,lk->nil", A, g.covariances().astype(np.float64), A)
    return means, cov, g.colors.astype(np.float64), g.opacities.astype(np.float64)


def template_view_colors(cloud_working, fits) -> dict[bool, np.ndarray]:
    """{from_below: (M, 3) float64 RGB in [0, 1]} of the template's Gaussians (the order of
    :func:`template_gaussians_local`) as the front (False: camera above the leaf, looking down its
    -Z) and back (True) textures see them: the SH, in the working frame, evaluated for the
    camera -> Gaussian direction of each view (the DC colour alone for SH degree 0)."""
    from leaffit_usd.splats.sh import eval_sh

    row = _template_row(fits)
    leaf = np.asarray(fits.leaf_to_working[row], np.float64)[:3, :3]
    idx = np.asarray(fits.template_gaussians, np.int64)
    idx = idx[(idx >= 0) & (idx < len(cloud_working))]
    sh = cloud_working.sh[idx]
    out = {}
    for from_below, d_local in ((False, (0.0, 0.0, -1.0)), (True, (0.0, 0.0, 1.0))):
        d = leaf @ np.asarray(d_local)
        out[from_below] = np.clip(eval_sh(sh, d / np.linalg.norm(d)), 0.0, 1.0)
    return out


def _template_row(fits) -> int:
    rows = np.flatnonzero(np.asarray(fits.leaf_labels) == fits.template_label)
    if len(rows) == 0:
        raise ParameterError("fits.leaf_labels", f"a row for the template leaf {fits.template_label}",
                             np.asarray(fits.leaf_labels).tolist())
    return int(rows[0])


def _dilate_colors(rgb: np.ndarray, solid: np.ndarray) -> np.ndarray:
    """Every non-solid texel takes the colour of its nearest solid texel (edge padding to infinity)."""
    from scipy.ndimage import distance_transform_edt

    if solid.all() or not solid.any():
        return rgb
    _, (ri, ci) = distance_transform_edt(~solid, return_indices=True)
    return rgb[ri, ci]


def _clean_mask(mask: np.ndarray, sheet_mask: np.ndarray) -> np.ndarray:
    """Closing (disk of radius ``max(2, size/128)`` texels: closes nicks where the capture's
    margin is sparse, keeps serration teeth), holes filled, within the sheet (+2 texels),
    components smaller than 1 % of the largest removed."""
    from scipy.ndimage import binary_closing, binary_dilation, binary_fill_holes, label

    if not mask.any():
        return mask
    rc = max(2, int(round(max(mask.shape) / 128)))
    yy, xx = np.mgrid[-rc:rc + 1, -rc:rc + 1]
    disk = xx * xx + yy * yy <= rc * rc
    m = binary_closing(np.pad(mask, rc + 1), structure=disk)[rc + 1:-rc - 1, rc + 1:-rc - 1] | mask
    if sheet_mask.any():
        yy, xx = np.mgrid[-2:3, -2:3]
        m &= binary_dilation(sheet_mask, structure=xx * xx + yy * yy <= 4)
    m = binary_fill_holes(m)
    lab, n = label(m)
    if n > 1:
        sizes = np.bincount(lab.ravel())[1:]
        m = np.isin(lab, 1 + np.flatnonzero(sizes >= 0.01 * sizes.max()))
    return m


def _side_texture(color: np.ndarray, alpha: np.ndarray, thr: float, sheet_mask: np.ndarray):
    """RGBA float (H, W, 4) straight alpha from a premultiplied render (color (H, W, 3), alpha
    (H, W)), and the splat coverage of the sheet's silhouette."""

    straight = color / np.maximum(alpha, 1e-6)[..., None]
    straight = np.clip(straight, 0.0, 1.0)
    # opaque inside (pin-holes and one-or-two-texel nicks closed), specks off the rim dropped
    solid = _clean_mask(alpha > thr, sheet_mask)
    # a one-texel anti-aliased rim: texels just outside the cut take alpha / thr, the rest 0
    from scipy.ndimage import distance_transform_edt

    rim = (distance_transform_edt(~solid) <= 1.5) & ~solid if solid.any() else np.zeros_like(solid)
    a = np.where(solid, 1.0, np.where(rim, np.clip(alpha / thr, 0.0, 1.0), 0.0))
    # nothing outside the sheet is ever drawn: keep alpha within the sheet's silhouette (+2 texels)
    # so splats beyond the rim (or stray ones) never reach the image border
    if sheet_mask.any():
        a = np.where(distance_transform_edt(~sheet_mask) <= 2.0, a, 0.0)
    cover = float((alpha > thr)[sheet_mask].mean()) if sheet_mask.any() else 0.0
    rgb = _dilate_colors(straight, alpha > 0.9 * thr)
    return np.concatenate([rgb, a[..., None]], -1), cover


def _inpainted(tex: np.ndarray, sheet_mask: np.ndarray, thr: float) -> np.ndarray:
    """Colour of the covered texels spread over the whole image; alpha = the sheet silhouette."""
    solid = tex[..., 3] > thr
    rgb = _dilate_colors(tex[..., :3], solid) if solid.any() else np.full_like(tex[..., :3], 0.3)
    return np.concatenate([rgb, sheet_mask[..., None].astype(np.float64)], -1)


def signed_sheet_offset(points: np.ndarray, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(M,) signed distance of each point to the sheet along the closest face's normal (+ = front)."""
    import open3d as o3d

    if len(points) == 0 or len(faces) == 0:
        return np.zeros(len(points))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(verts, np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)))
    r = scene.compute_closest_points(o3d.core.Tensor(np.ascontiguousarray(points, np.float32)))
    cp, n = r["points"].numpy().astype(np.float64), r["primitive_normals"].numpy().astype(np.float64)
    return ((points - cp) * n).sum(1)


def bake_textures(cloud_working, fits, sheet_points: np.ndarray, sheet_faces: np.ndarray,
                  outline_xy: np.ndarray, bounds, size: int, thr: float = 0.5,
                  min_coverage: float = 0.6, supersample: int = 1):
    """Front and back RGBA float textures (H, W, 4) in [0, 1], straight alpha, row 0 = top.

    Colours are view-dependent: each texture evaluates the Gaussians' SH (working frame) for its
    own view direction, down onto the front and up onto the back (:func:`template_view_colors`).

    sheet_points, sheet_faces : the sheet (template frame, CCW from +Z). A capture of a leaf holds
        a layer of Gaussians on each side of the blade; each side is its own layer (Gaussians on
        that side of the sheet: signed offset along the closest face's normal) composited over
        the other layer, so the global depth sort of the rasteriser cannot mix the two layers
        where the blade is tilted in the view, and gaps in one layer show the other.
    outline_xy : (k, 2) the sheet's outer boundary, template frame (coverage and fallbacks)
    bounds : the front texture's (xmin, xmax, ymin, ymax), template frame; the back texture is
        its mirror image (column c of the back = column W-1-c of the front)
    Returns (front, back, info) with coverage figures and the fallback used, if any.
    """
    from leaffit_usd.splats.render import render_orthographic_np

    means, cov, _, opac = template_gaussians_local(cloud_working, fits)
    view_colors = template_view_colors(cloud_working, fits)  # view-dependent (SH) per side
    mask = rasterize_polygon(outline_xy, size, size, bounds)
    info = {}
    if len(means) == 0:
        log.warning("mesh: the template has no Gaussians to bake; textures are flat grey")
        flat = np.concatenate([np.full((size, size, 3), 0.3), mask[..., None]], -1)
        return flat, flat[:, ::-1].copy(), dict(coverage_front=0.0, coverage_back=0.0,
                                                 texture_fallback="flat")
    t0 = time.perf_counter()
    off = signed_sheet_offset(means, sheet_points, sheet_faces)
    info["front_gaussians"] = int((off >= 0).sum())
    info["back_gaussians"] = int((off < 0).sum())

    ss = max(int(supersample), 1)

    def render(sel, from_below):
        """Premultiplied colour (H, W, 3) and alpha (H, W), rendered ss x ss per texel and
        box-filtered (the average of premultiplied samples: dividing by the averaged alpha
        later gives the coverage-weighted colour, true to the input at the rim)."""
        sel = np.flatnonzero(sel)
        if len(sel) == 0:
            z = np.zeros((size, size))
            return z[..., None].repeat(3, -1), z
        n = size * ss
        r = render_orthographic_np(means[sel], cov[sel], view_colors[from_below][sel], opac[sel],
                                   n, n, bounds, from_below=from_below)
        c = np.asarray(r.color, np.float64).reshape(size, ss, size, ss, 3).mean((1, 3))
        a = np.asarray(r.alpha, np.float64).reshape(size, ss, size, ss).mean((1, 3))
        return c, a

    def side(own_sel, from_below):
        """The side's own layer composited over the other layer (premultiplied 'over')."""
        c1, a1 = render(own_sel, from_below)
        c2, a2 = render(~own_sel, from_below)
        own_cover = float((a1 > thr)[mask].mean()) if mask.any() else 0.0
        return (c1 + (1 - a1)[..., None] * c2, a1 + (1 - a1) * a2), own_cover

    front_sel = off >= 0
    (fc, fa), own_f = side(front_sel, False)
    (bc, ba), own_b = side(~front_sel, True)   # registered with the front (not mirrored yet)
    front, cf = _side_texture(fc, fa, thr, mask)
    back_reg, cb = _side_texture(bc, ba, thr, mask)
    info["own_layer_coverage_front"], info["own_layer_coverage_back"] = own_f, own_b
    one_layer = [nm for nm, c in (("front", own_f), ("back", own_b)) if c < min_coverage]
    if one_layer:
        log.warning("mesh: the leaf's %s side has few Gaussians of its own (seen from one side "
                    "only?); that texture shows the other layer", " and ".join(one_layer))
    info["one_layer_sides"] = one_layer
    info["bake_seconds"] = time.perf_counter() - t0
    info["coverage_front"], info["coverage_back"] = cf, cb
    fallback = None
    if cf < min_coverage and cb < min_coverage:
        fallback = "inpainted"
        log.warning("mesh: the template's splats cover only %.0f%% (front) / %.0f%% (back) of the "
                    "leaf; textures are inpainted over the mesh silhouette", 100 * cf, 100 * cb)
        front, back_reg = _inpainted(front, mask, thr), _inpainted(back_reg, mask, thr)
    elif cb < min_coverage:
        fallback = "back_from_front"
        log.warning("mesh: the leaf's back is covered only %.0f%%; the back texture reuses the "
                    "front", 100 * cb)
        back_reg = front.copy()
    elif cf < min_coverage:
        fallback = "front_from_back"
        log.warning("mesh: the leaf's front is covered only %.0f%%; the front texture reuses the "
                    "back", 100 * cf)
        front = back_reg.copy()
    info["texture_fallback"] = fallback
    info["alpha_coverage_front"] = float((front[..., 3] > thr).mean())
    info["alpha_coverage_back"] = float((back_reg[..., 3] > thr).mean())
    return front, back_reg[:, ::-1].copy(), info


def _to_u8(tex: np.ndarray) -> np.ndarray:
    return np.clip(np.round(tex * 255.0), 0, 255).astype(np.uint8)


# ---- main entry --------------------------------------------------------------------------------------
def build_template_mesh(cloud_working, fits, params: MeshParams | None = None) -> TemplateMesh:
    """Two-sided, textured template leaf mesh.

    cloud_working : GaussianCloud, working frame (the cloud the fit ran on)
    fits : LeafFits (template_points, template_gaussians, leaf_to_working of the template row)
    Returns a :class:`TemplateMesh` in the template local frame (working units).
    """
    params = params or MeshParams()
    params.validate()
    timings = {}
    t0 = time.perf_counter()
    pts = np.asarray(fits.template_points, np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(1)]
    _template_row(fits)  # fail early on a LeafFits without the template's row
    idx = farthest_point_sampling(pts, int(params.vertex_budget)) if len(pts) else np.zeros(0, np.int64)
    samples = pts[idx]
    timings["fps"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sheet, checks = build_sheet(samples, params)
    timings["surface"] = time.perf_counter() - t0
    rim_sheet = sheet
    t0 = time.perf_counter()
    if params.clean_outline and len(sheet.faces):
        clean = surf.remesh_sheet(sheet.points, sheet.faces, len(sheet.points))
        if clean is None:
            log.info("mesh: the template sheet is not a height field in its frame; keeping its "
                     "own outline")
        else:
            clean.info.update({k: v for k, v in sheet.info.items() if k not in clean.info})
            clean.info["method"] = f"{sheet.info.get('method')}+outline"
            sheet = clean
            checks = {**checks, **surf.sheet_checks(sheet.points, sheet.faces)}
    timings["outline"] = time.perf_counter() - t0
    P = sheet.points
    Fs = sheet.faces.astype(np.int64)
    S = len(P)
    loops = surf.boundary_loops(Fs, S)
    outer = max(loops, key=lambda lp: abs(surf.signed_area_xy(P[lp]))) if loops else np.arange(S)

    # UVs and textures
    size = int(params.texture_size)
    t0 = time.perf_counter()
    bounds = chart_bounds(P[:, :2], params.texture_margin, size) if params.uv_layout == "fit" else \
        uv_bounds(P[:, :2], size, params.texture_margin)
    front, back, tinfo = bake_textures(cloud_working, fits, P, Fs, P[outer, :2], bounds, size,
                                       params.alpha_threshold, params.min_coverage,
                                       int(params.supersample))
    timings["bake"] = time.perf_counter() - t0

    lod0 = two_sided(P, Fs, bounds)
    mesh = TemplateMesh(
        points=lod0.points, faces=lod0.faces, normals=lod0.normals, uvs=lod0.uvs, side=lod0.side,
        front_texture=_to_u8(front), back_texture=_to_u8(back),
        sheet_points=P.astype(np.float32), sheet_faces=Fs.astype(np.int32),
    )
    t0 = time.perf_counter()
    mesh.lods = [two_sided(*lod_sheet(rim_sheet, P, Fs, int(n)), bounds) for n in params.lod_vertices]
    timings["lods"] = time.perf_counter() - t0
    mesh.report = quality_report(mesh, cloud_working, fits, sheet, checks, tinfo, bounds, params)
    mesh.report["lod_vertices_per_side"] = [int(S)] + [int(len(l.points) // 2) for l in mesh.lods]
    mesh.report["timings"] = {k: round(v, 4) for k, v in timings.items()}
    return mesh


def two_sided(P: np.ndarray, F: np.ndarray, bounds) -> TemplateLOD:
    """The two-sided layout of a sheet (points (S, 3), faces (G, 3)): front copy (CCW from +Z,
    normals, uv into the front texture) then back copy (reversed winding, negated normals,
    u mirrored into the back texture)."""
    P = np.asarray(P, np.float64)
    F = np.asarray(F, np.int64)
    S = len(P)
    normals = vertex_normals(P, F, undefined=(0.0, 0.0, 1.0))
    uv_front = planar_uvs(P[:, :2], bounds)
    uv_back = np.stack([1.0 - uv_front[:, 0], uv_front[:, 1]], 1)
    return TemplateLOD(points=np.concatenate([P, P]).astype(np.float32),
                       faces=np.concatenate([F, F[:, ::-1] + S]).astype(np.int32),
                       normals=np.concatenate([normals, -normals]).astype(np.float32),
                       uvs=np.concatenate([uv_front, uv_back]).astype(np.float32),
                       side=np.concatenate([np.zeros(S, np.uint8), np.ones(S, np.uint8)]))


def lod_sheet(rim_sheet, P: np.ndarray, F: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A coarser sheet of about ``n`` vertices: the clean-outline re-triangulation of the
    surface, or (not a height field) open3d's quadric decimation of the LOD0 sheet."""
    if n >= len(P):
        return P, F
    src = rim_sheet if len(rim_sheet.faces) else None
    if src is not None:
        lod = surf.remesh_sheet(src.points, src.faces, n)
        if lod is not None:
            return lod.points, lod.faces
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(P, np.float64)),
                                  o3d.utility.Vector3iVector(np.asarray(F, np.int32)))
    d = m.simplify_quadric_decimation(target_number_of_triangles=max(2 * n - 2, 2))
    d.remove_unreferenced_vertices()
    return np.asarray(d.vertices, np.float64), np.asarray(d.triangles, np.int64)


def quality_report(mesh: TemplateMesh, cloud_working, fits, sheet, checks, tinfo, bounds, params) -> dict:
    """Plain-JSON quality figures of a template mesh (distances relative to the leaf length)."""
    P, F = mesh.sheet_points.astype(np.float64), mesh.sheet_faces.astype(np.int64)
    pts = np.asarray(fits.template_points, np.float64)
    pts = pts[np.isfinite(pts).all(1)]
    leaf_len = float(np.ptp(pts[:, 0])) if len(pts) else 1.0
    leaf_len = leaf_len if leaf_len > 0 else 1.0
    rep = dict(
        method=sheet.info.get("method"), vertex_budget=int(params.vertex_budget),
        sheet_vertices=int(len(P)), sheet_faces=int(len(F)),
        vertices=int(len(mesh.points)), faces=int(len(mesh.faces)),
        leaf_length=leaf_len,
        holes_before=int(sheet.info.get("holes_before", 0)),
        holes_after=int(max(checks.get("boundary_loops", 1) - 1, 0)),
        islands_removed=int(sheet.info.get("islands_removed", 0)),
        slivers_removed=int(sheet.info.get("slivers_removed", 0)),
        unused_samples=int(sheet.info.get("unused_samples", 0)),
    )
    rep.update({k: v for k, v in checks.items()})
    if len(F):
        loops = surf.boundary_loops(F, len(P))
        blen = sum(float(np.linalg.norm(P[lp] - P[np.roll(lp, -1)], axis=1).sum()) for lp in loops)
        rep["boundary_length"] = blen
        rep["boundary_length_rel"] = blen / leaf_len
        d = point_sheet_distance(pts, P, F) / leaf_len
        rep.update(points_dist_mean_rel=float(d.mean()) if len(d) else 0.0,
                   points_dist_max_rel=float(d.max()) if len(d) else 0.0)
        try:
            means, _, _, _ = template_gaussians_local(cloud_working, fits)
            g = point_sheet_distance(means, P, F) / leaf_len
            rep.update(gauss_dist_mean_rel=float(g.mean()) if len(g) else 0.0,
                       gauss_dist_p95_rel=float(np.percentile(g, 95)) if len(g) else 0.0,
                       gauss_dist_max_rel=float(g.max()) if len(g) else 0.0)
        except Exception as exc:  # report only
            log.debug("mesh: Gaussian distance report skipped: %s", exc)
        # planar-UV stretch: 3D edge length / (xy edge length)
        e = F[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
        l3 = np.linalg.norm(P[e[:, 0]] - P[e[:, 1]], axis=1)
        l2 = np.linalg.norm(P[e[:, 0], :2] - P[e[:, 1], :2], axis=1)
        stretch = l3 / np.maximum(l2, 1e-12)
        rep["uv_stretch_max"] = float(stretch.max())
        rep["uv_stretch_p99"] = float(np.percentile(stretch, 99))
        ang = surf.tri_min_angle(P, F)
        rep["min_angle_deg_p5"] = float(np.percentile(ang, 5))
    rep.update({k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in tinfo.items()})
    rep["texture_size"] = int(params.texture_size)
    rep["uv_bounds"] = [float(b) for b in bounds]
    return rep


# ---- texture files ------------------------------------------------------------------------------------
class TexturePaths(NamedTuple):
    """Paths of the two texture files written by :func:`write_textures`."""

    front: Path
    back: Path


def write_textures(mesh: TemplateMesh, directory, fmt: str = "png", basename: str = "leaf") -> TexturePaths:
    """Write ``<basename>_front.<fmt>`` and ``<basename>_back.<fmt>`` into ``directory``, atomically."""
    if fmt not in FORMATS:
        raise ParameterError("fmt", " or ".join(FORMATS), fmt)
    d = Path(directory)
    front = d / f"{basename}_front.{fmt}"
    back = d / f"{basename}_back.{fmt}"
    write_image(front, mesh.front_texture)
    write_image(back, mesh.back_texture)
    return TexturePaths(front, back)
