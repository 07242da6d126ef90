"""Choice of the template's surface: ball pivoting, else the planar alpha shape, else a quad.

Each candidate must be a single disk (:func:`surface.sheet_checks`) with at most
``MAX_OFF_SHEET_FRACTION`` of the samples farther than one sample spacing from it; the first
that passes wins, with a warning naming what failed before it.
"""
from __future__ import annotations

import logging

import numpy as np

from leaffit_usd.mesh import surface as surf
from leaffit_usd.mesh.params import MeshParams
from leaffit_usd.mesh.sheet_distance import point_sheet_distance

log = logging.getLogger("leaffit_usd")

MAX_OFF_SHEET_FRACTION = 0.02  # samples farther than one spacing from the sheet (rim left out)


def _off_sheet_fraction(samples: np.ndarray, sheet: surf.Sheet, spacing: float) -> float:
    if len(sheet.faces) == 0:
        return 1.0
    d = point_sheet_distance(samples, sheet.points, sheet.faces)
    return float(np.mean(d > spacing))

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
