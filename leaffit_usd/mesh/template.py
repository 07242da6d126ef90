"""Template leaf mesh: surface, two-sided UVs and texture bake (paper, "Template Leaf Mesh Extraction").

Pipeline (template local frame: petiole base at the origin, +X base -> apex, +Z leaf normal):

1. **Samples** — farthest point sampling of the template's denoised Gaussian centres
   (``fits.template_points``) down to ``vertex_budget`` (2,048, the paper's). Hole filling adds
   no vertices, so the sheet has at most that many vertices (fewer when BPA leaves samples out).
   The budget counts the *sheet's* vertices (geometric positions); the two-sided mesh duplicates
   each per side, so ``TemplateMesh.points`` has twice as many rows.
   **Sheet view**: the samples are turned so +Z is the leaf's mean normal when the fit's +Z is
   more than 30 degrees from it (an arched strap leaf, edge-on in the fit's frame:
   :mod:`leaffit_usd.mesh.view_frame`); steps 2-5 work in that view, the mesh is returned in
   the template frame.
2. **Surface** — ball pivoting + repair (the paper's), or the planar fallback, see
   :mod:`leaffit_usd.mesh.surface`. ``method="auto"`` runs BPA and falls back to planar when the
   repaired BPA sheet fails the disk/thin checks, with a warning.
   The clean outline grows out to the template splats' silhouette (the centres stop short of
   the leaf's edge: :mod:`leaffit_usd.mesh.outline_fit`).
3. **UVs** — from the template frame's xy (the PCA-aligned view the fit uses), through a chart
   (:class:`leaffit_usd.mesh.uv_chart.UVChart`). Chosen over xatlas because the bake is an
   orthographic render along +-Z of that very frame (no seams, one island per side, front and
   back registered, the texture reads as a picture of the leaf). The default ``envelope`` chart
   keeps u = base -> apex and straightens and widens every column of the leaf across the
   texture, so the leaf fills it (a cordate leaf covers ~65 % of its bounding box); the
   Gaussians are carried into the chart's coordinates by its Jacobian and rendered there, so a
   texel is still a render pixel. ``fit`` / ``square`` are the planar charts. The cost: stretch
   where the leaf's surface is steep in this view (strongly curled leaves; the report gives
   ``uv_stretch_max``, largest 3D/2D edge length ratio) and, between vertices, the linear
   interpolation of the chart's smooth map (``uv_interpolation_texels_max``).
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
   silhouette. Not on a leaf seen in a tilted sheet view (an arched strap leaf): its steep
   parts are seen nearly edge-on, their splats leave gaps that are no edge of the leaf (lucky
   bamboo: notches along both margins and a cut halfway across the blade), so alpha is the
   sheet's own silhouette there, as the outline term of the fit is only used on a leaf seen
   face-on. Colours are then dilated outwards over the whole image (nearest covered texel) so
   mip-maps never bleed background into the leaf. DC colours only: the cloud's SH rest
   coefficients are not rotated into the working frame.

Fallbacks (each with a warning): a side with few Gaussians of its own (a leaf seen from one side
only) shows the other layer — reported as ``one_layer_sides``; a side still covering less than
``min_coverage`` of the sheet's silhouette takes the other side's texture; when both are poor (a
sparse capture) colours are inpainted over the sheet and alpha = the sheet.

This module assembles the steps; each has its own module: parameters (:mod:`.params`), the
surface choice (:mod:`.sheet_choice`), UVs (:mod:`.uv_chart`), the bake (:mod:`.texture_bake`,
:mod:`.texture_alpha`, :mod:`.template_gaussians`), the report (:mod:`.quality_report`) and the
texture files (:mod:`.texture_files`).
"""
from __future__ import annotations

import logging
import time
from dataclasses import replace

import numpy as np

from leaffit_usd.geometry.normals import vertex_normals
from leaffit_usd.geometry.sampling import farthest_point_sampling
from leaffit_usd.mesh import surface as surf
from leaffit_usd.mesh.params import MeshParams
from leaffit_usd.mesh.quality_report import quality_report
from leaffit_usd.mesh.result import TemplateLOD, TemplateMesh
from leaffit_usd.mesh.sheet_choice import build_sheet
from leaffit_usd.mesh.outline_fit import silhouette_outline, splat_alpha_image
from leaffit_usd.mesh.template_gaussians import template_gaussians_local, template_row
from leaffit_usd.mesh.texture_bake import bake_textures
from leaffit_usd.mesh.texture_files import to_u8, write_textures
from leaffit_usd.mesh.uv_chart import UVChart, envelope_chart, planar_chart
from leaffit_usd.mesh.view_frame import sheet_view_rotation

log = logging.getLogger("leaffit_usd")

__all__ = ["MeshParams", "build_template_mesh", "two_sided", "lod_sheet", "write_textures"]


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
    template_row(fits)  # fail early on a LeafFits without the template's row
    idx = farthest_point_sampling(pts, int(params.vertex_budget)) if len(pts) else np.zeros(0, np.int64)
    samples = pts[idx]
    # the sheet is built, charted and baked looking along the leaf's mean normal (the identity
    # unless the fit's +Z is far from it: an arched strap leaf seen edge-on, view_frame.py)
    rot = sheet_view_rotation(samples) if len(samples) else np.eye(3)
    samples = samples @ rot.T
    timings["fps"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sheet, checks = build_sheet(samples, params)
    timings["surface"] = time.perf_counter() - t0
    rim_sheet = sheet
    t0 = time.perf_counter()
    grow = None
    if params.clean_outline and len(sheet.faces) and params.outline_grow > 0:
        grow = _silhouette_grow(cloud_working, fits, rot, samples, params)
    if params.clean_outline and len(sheet.faces):
        clean = surf.remesh_sheet(sheet.points, sheet.faces, len(sheet.points), grow=grow)
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
    ring = P[outer, :2]
    size = params.texture_side(float(np.ptp(ring, axis=0).max()) if len(ring) else 0.0,
                               abs(surf.signed_area_xy(ring)) if len(ring) >= 3 else 0.0,
                               len(fits.template_gaussians))
    t0 = time.perf_counter()
    if params.uv_layout == "envelope":
        chart = envelope_chart(P[outer, :2], size, params.texture_margin, params.chart_min_width)
    else:
        chart = planar_chart(P[:, :2], size, params.texture_margin, params.uv_layout)
    front, back, tinfo = bake_textures(cloud_working, fits, P, Fs, P[outer, :2], chart, size,
                                       params.alpha_threshold, params.min_coverage,
                                       int(params.supersample), int(params.bake_gaussians), rot,
                                       cut_out=bool(np.allclose(rot, np.eye(3))))
    timings["bake"] = time.perf_counter() - t0

    lod0 = two_sided(P, Fs, chart, rot)
    mesh = TemplateMesh(
        points=lod0.points, faces=lod0.faces, normals=lod0.normals, uvs=lod0.uvs, side=lod0.side,
        front_texture=to_u8(front), back_texture=to_u8(back),
        sheet_points=(P @ rot).astype(np.float32), sheet_faces=Fs.astype(np.int32),
    )
    t0 = time.perf_counter()
    mesh.lods = [two_sided(*lod_sheet(rim_sheet, P, Fs, int(n), grow), chart, rot)
                 for n in params.lod_budgets()]
    timings["lods"] = time.perf_counter() - t0
    mesh.report = quality_report(mesh, cloud_working, fits, sheet, checks, tinfo, chart,
                                 replace(params, texture_size=size), rot)
    mesh.report["lod_vertices_per_side"] = [int(S)] + [int(len(l.points) // 2) for l in mesh.lods]
    mesh.report["timings"] = {k: round(v, 4) for k, v in timings.items()}
    return mesh


def _silhouette_grow(cloud_working, fits, rot, samples, params: MeshParams):
    """The outline's growth out to the template splats' silhouette (:mod:`.outline_fit`), or
    None without Gaussians."""
    means, cov, _, opac = template_gaussians_local(cloud_working, fits, rot)
    if len(means) < 3 or len(samples) < 2:
        return None
    max_out = float(params.outline_grow) * surf.sample_spacing(samples)
    alpha, bounds = splat_alpha_image(means, cov, opac, pad=2.0 * max_out)
    return silhouette_outline(alpha, bounds, float(params.alpha_threshold), max_out)


def two_sided(P: np.ndarray, F: np.ndarray, chart: UVChart, rotation=None) -> TemplateLOD:
    """The two-sided layout of a sheet (points (S, 3), faces (G, 3)): front copy (CCW from +Z,
    normals, uv into the front texture) then back copy (reversed winding, negated normals,
    u mirrored into the back texture).

    P is in the frame the chart reads (xy); with ``rotation`` (3, 3, template -> sheet view) P is
    in the sheet view and the points and normals are returned in the template frame."""
    P = np.asarray(P, np.float64)
    F = np.asarray(F, np.int64)
    S = len(P)
    normals = vertex_normals(P, F, undefined=(0.0, 0.0, 1.0))
    uv_front = chart.uv(P[:, :2])
    uv_back = np.stack([1.0 - uv_front[:, 0], uv_front[:, 1]], 1)
    if rotation is not None:
        R = np.asarray(rotation, np.float64)
        P, normals = P @ R, normals @ R
    return TemplateLOD(points=np.concatenate([P, P]).astype(np.float32),
                       faces=np.concatenate([F, F[:, ::-1] + S]).astype(np.int32),
                       normals=np.concatenate([normals, -normals]).astype(np.float32),
                       uvs=np.concatenate([uv_front, uv_back]).astype(np.float32),
                       side=np.concatenate([np.zeros(S, np.uint8), np.ones(S, np.uint8)]))


def lod_sheet(rim_sheet, P: np.ndarray, F: np.ndarray, n: int, grow=None) -> tuple[np.ndarray, np.ndarray]:
    """A coarser sheet of about ``n`` vertices: the clean-outline re-triangulation of the
    surface (its outline grown as LOD0's, ``grow``), or (not a height field) open3d's quadric
    decimation of the LOD0 sheet."""
    if n >= len(P):
        return P, F
    src = rim_sheet if len(rim_sheet.faces) else None
    if src is not None:
        lod = surf.remesh_sheet(src.points, src.faces, n, grow=grow)
        if lod is not None:
            return lod.points, lod.faces
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(P, np.float64)),
                                  o3d.utility.Vector3iVector(np.asarray(F, np.int32)))
    d = m.simplify_quadric_decimation(target_number_of_triangles=max(2 * n - 2, 2))
    d.remove_unreferenced_vertices()
    return np.asarray(d.vertices, np.float64), np.asarray(d.triangles, np.int64)
