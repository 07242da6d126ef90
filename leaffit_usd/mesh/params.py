"""Template mesh parameters (:class:`MeshParams`), the one place their defaults are written."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from leaffit_usd.errors import ParameterError

METHODS = ("auto", "bpa", "planar")
UV_LAYOUTS = ("envelope", "fit", "square")
#: the smallest texture side the texel density may choose, pixels
MIN_TEXTURE_SIZE = 128


@dataclass
class MeshParams:
    """Template mesh parameters.

    vertex_budget : maximum number of sheet vertices (FPS samples), paper: 2,048
    texture_size : the largest width = height of each side's baked texture in pixels
        (``convert --bake-size``; the stage's files may be downsampled when written:
        ``WriteOptions.texture_max_size``)
    texels_per_spacing : the texture follows the template's texel density: its side is the
        power of two (at least ``MIN_TEXTURE_SIZE``, at most ``texture_size``) that gives this many
        texels per spacing of the template's Gaussians (sqrt(leaf area / Gaussians)) along the
        leaf's longer extent; 0 = always ``texture_size``. Why 2 (Nyquist): the splats cannot
        show detail finer than their spacing, and a 100k-Gaussian plant's template (4-9k
        Gaussians) gets 256-512 px instead of 1024 px, a quarter of the bake and of the file
        (render fidelity: ``benchmarks/render.py``). Range [0, 16].
    method : "auto" (BPA, planar fallback), "bpa" (BPA only; still falls back when it produces
        nothing usable) or "planar"
    bpa_radii : ball radii, multiples of the samples' median nearest-neighbour spacing
    alpha : planar method's alpha-shape circumradius, multiple of the same spacing
    texture_margin : empty border around the leaf in the texture, fraction of its extent
    uv_layout : "envelope" (each column of the leaf, base -> apex, is straightened and widened
        across the texture: the leaf fills it, :class:`uv_chart.UVChart`), "fit" (planar: the
        chart's bounding box fills the square texture, texels follow the leaf's aspect ratio)
        or "square" (planar, square texels, the leaf's larger extent spans it)
    chart_min_width : the envelope chart widens no column less than this fraction of the leaf's
        largest half-width (limits the stretch at the base and the apex)
    supersample : the bake renders at this many times the texture size per axis and
        box-filters down (premultiplied), then divides by the accumulated alpha. 1 (was 2): at
        the texel density's 2 texels per Gaussian spacing the render is already oversampled;
        green pepper 100k, 512^2: ss 1 vs 2 PSNR 53.6 dB inside the leaf, cut-out IoU 0.9994,
        mesh stage CPU 6.5 -> 3.0 s. Range 1..4.
    clean_outline : re-triangulate the sheet inside a smooth outline curve (constrained
        Delaunay, :func:`surface.remesh_sheet`); the fine serration stays in the alpha cut-out
    outline_grow : the clean outline grows out to the template splats' silhouette (alpha =
        ``alpha_threshold``), at most this many sample spacings (:mod:`.outline_fit`; the
        Gaussians' centres stop short of the leaf's edge); 0 = the outline stays on the centres
    lod_vertices : vertex budgets of the coarser levels of detail (per side), each below the
        last and below ``vertex_budget``; None (default) = a quarter and a sixteenth of
        ``vertex_budget`` (512 and 128 at the default 2,048; a level under 8 vertices is left out),
        see :meth:`lod_budgets`
    alpha_threshold : splat coverage at which the cut-out edge lies
    min_coverage : smallest fraction of the sheet's silhouette a side's splats must cover
    bake_gaussians : the bake renders at most this many of the template's Gaussians (an even
        subset, widened to cover for the rest; 0 = all): dense captures bake in bounded time
        (:func:`leaffit_usd.mesh.texture_bake.bake_subset`)
    """

    vertex_budget: int = 2048
    texture_size: int = 1024
    texels_per_spacing: float = 2.0
    method: str = "auto"
    bpa_radii: tuple = (2.0, 3.0, 4.0)
    alpha: float = 2.5
    texture_margin: float = 0.01
    uv_layout: str = "envelope"
    chart_min_width: float = 0.3
    supersample: int = 1
    clean_outline: bool = True
    outline_grow: float = 6.0
    lod_vertices: tuple | None = None
    alpha_threshold: float = 0.5
    min_coverage: float = 0.6
    bake_gaussians: int = 65536

    def lod_budgets(self) -> tuple:
        """The coarser levels' vertex budgets (per side): ``lod_vertices``, or by default a
        quarter and a sixteenth of the vertex budget (at least 8)."""
        if self.lod_vertices is not None:
            return tuple(self.lod_vertices)
        out, last = [], int(self.vertex_budget)
        for n in (last // 4, last // 16):   # a level too small to be coarser is left out
            if 8 <= n < last:
                out.append(n)
                last = n
        return tuple(out)

    def texture_side(self, extent: float, area: float, n_gaussians: int) -> int:
        """The texture's side in pixels for a template leaf of longer extent ``extent`` and area
        ``area`` (working units, its plane) holding ``n_gaussians`` Gaussians (see
        ``texels_per_spacing``)."""
        top = int(self.texture_size)
        if self.texels_per_spacing <= 0 or n_gaussians <= 0 or not (area > 0 and extent > 0):
            return top
        want = self.texels_per_spacing * extent / np.sqrt(area / n_gaussians)
        side = MIN_TEXTURE_SIZE
        while side < want and side < top:
            side *= 2
        return int(min(side, top))

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
        if self.uv_layout not in UV_LAYOUTS:
            raise ParameterError("uv_layout", ", ".join(UV_LAYOUTS), self.uv_layout)
        if not isinstance(self.supersample, (int, np.integer)) or not 1 <= self.supersample <= 4:
            raise ParameterError("supersample", "an integer in 1..4", self.supersample)
        if not isinstance(self.bake_gaussians, (int, np.integer)) or isinstance(self.bake_gaussians, bool) \
                or self.bake_gaussians < 0:
            raise ParameterError("bake_gaussians", "an integer >= 0 (0 = all)", self.bake_gaussians)
        lods = self.lod_budgets()
        if not all(isinstance(n, (int, np.integer)) and n >= 8 for n in lods):
            raise ParameterError("lod_vertices", "integers >= 8", self.lod_vertices)
        if any(b >= a for a, b in zip((self.vertex_budget, *lods), lods)):
            raise ParameterError("lod_vertices", f"budgets each below the last and below the vertex "
                                 f"budget ({self.vertex_budget}): a coarser level of detail", lods)
        for name, lo, hi in (("texels_per_spacing", 0.0, 16.0), ("alpha", 0.5, 100.0), ("texture_margin", 0.0, 0.45), ("outline_grow", 0.0, 10.0),
                             ("alpha_threshold", 0.01, 0.99), ("chart_min_width", 0.05, 1.0),
                             ("min_coverage", 0.0, 1.0)):
            v = getattr(self, name)
            if not (np.isfinite(v) and lo <= v <= hi):
                raise ParameterError(name, f"a number in [{lo}, {hi}]", v)
