"""Plain-JSON quality figures of a template mesh (the ``mesh`` part of ``convert --report``)."""
from __future__ import annotations

import logging

import numpy as np

from leaffit_usd.mesh import surface as surf
from leaffit_usd.mesh.result import TemplateMesh
from leaffit_usd.mesh.sheet_distance import point_sheet_distance
from leaffit_usd.mesh.template_gaussians import template_gaussians_local

log = logging.getLogger("leaffit_usd")


def quality_report(mesh: TemplateMesh, cloud_working, fits, sheet, checks, tinfo, chart, params,
                   rotation=None) -> dict:
    """Plain-JSON quality figures of a template mesh (distances relative to the leaf length).

    rotation : (3, 3) template -> sheet view (the frame the chart reads), None = identity."""
    P, F = mesh.sheet_points.astype(np.float64), mesh.sheet_faces.astype(np.int64)
    R = np.eye(3) if rotation is None else np.asarray(rotation, np.float64)
    Pv = P @ R.T                       # the sheet as the chart sees it
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
        l2 = np.linalg.norm(Pv[e[:, 0], :2] - Pv[e[:, 1], :2], axis=1)
        stretch = l3 / np.maximum(l2, 1e-12)
        rep["uv_stretch_max"] = float(stretch.max())
        rep["uv_stretch_p99"] = float(np.percentile(stretch, 99))
        ang = surf.tri_min_angle(P, F)
        rep["min_angle_deg_p5"] = float(np.percentile(ang, 5))
    rep.update({k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in tinfo.items()})
    rep["texture_size"] = int(params.texture_size)
    rep["uv_chart"] = chart.kind
    rep["sheet_view_tilt_deg"] = float(np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0))))
    rep["uv_bounds"] = [float(b) for b in chart.bounds]
    if len(F):
        # the texels between vertices follow the uv interpolated linearly, not the chart's map:
        # the largest gap at the triangles' centroids, in texels
        cen = Pv[F].mean(1)
        interp = mesh.uvs[: len(P)][F].astype(np.float64).mean(1)
        gap = np.abs(interp - chart.uv(cen[:, :2])) * float(params.texture_size)
        rep["uv_interpolation_texels_max"] = float(gap.max())
    return rep
