"""Leaf blades for the sample generator: parametric outlines, the curved sheet, its GT mesh, colour.

Leaf 2D frame (``outline``): the blade base (where the petiole joins) at the origin, the main
apex at (1, 0); x along the midrib, y across, lengths in blade lengths (base-to-apex = 1).
Cordate and palmate outlines extend behind the base (x < 0) around the basal sinus.

Leaf local 3D frame (``LeafSheet.local``): the same origin and x axis, +z the upper (adaxial)
side of the blade, metres. The sheet is a star-shaped polar mesh (rays from an interior centre
to the outline vertices, ``rings`` rings) so every outline, lobed or serrated, meshes cleanly;
its faces are ordered counter-clockwise seen from +z, so face normals point to the upper side.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# ---------------------------------------------------------------------------------------------
# outlines
# ---------------------------------------------------------------------------------------------

#: Outline presets. ``family``: "width" (half-width profile w(u) = W u^a (1-u)^b / max) or
#: "cordate" / "palmate" (polar). ``venation``: pinnate | palmate | parallel.
SHAPES: dict[str, dict] = {
    "elliptic": dict(family="width", W=0.24, a=0.6, b=0.75, venation="pinnate"),
    "rubber": dict(family="width", W=0.23, a=0.55, b=0.95, venation="pinnate", tip=0.06),
    "ovate": dict(family="width", W=0.30, a=0.42, b=1.05, venation="pinnate"),
    "obovate": dict(family="width", W=0.27, a=1.05, b=0.42, venation="pinnate"),
    "lanceolate": dict(family="width", W=0.11, a=0.5, b=1.25, venation="pinnate"),
    "linear": dict(family="width", W=0.065, a=0.28, b=0.75, venation="parallel", tip=0.08),
    "grass": dict(family="width", W=0.035, a=0.2, b=0.9, venation="parallel"),
    "cordate": dict(family="cordate", W=0.75, notch=0.55, tip=0.35, venation="palmate"),
    "cotton_rose": dict(family="palmate", lobes=5, spread=2.3, lengths=(1.0, 0.85, 0.55),
                        sinus=0.68, q=1.9, tip=0.06, lobe_width=0.9, venation="palmate",
                        base_notch=0.35),
    "maple": dict(family="palmate", lobes=5, spread=2.5, lengths=(1.0, 0.92, 0.5),
                  sinus=0.3, q=1.25, tip=0.1, lobe_width=0.72, venation="palmate", base_notch=0.15),
    "trilobed": dict(family="palmate", lobes=3, spread=1.5, lengths=(1.0, 0.7),
                     sinus=0.5, q=1.6, tip=0.08, lobe_width=0.75, venation="palmate", base_notch=0.3),
}

#: Shapes a plant ``kind`` draws from (weights implicit: uniform).
KIND_SHAPES = {
    "elliptic": ["elliptic", "rubber", "ovate", "obovate"],
    "lobed": ["cotton_rose", "maple", "trilobed"],
    "thin": ["linear", "lanceolate", "grass"],
    "cordate": ["cordate"],
}


@dataclass
class Outline:
    """A closed blade outline, leaf 2D frame (base at origin, apex at (1, 0)).

    poly : (M, 2) float64, counter-clockwise, uniform in arclength
    centre : (2,) float64, the polygon is star-shaped about it
    venation : "pinnate" | "palmate" | "parallel"
    lobe_dirs : (K,) float64, directions (radians, from +x, seen from the base) of primary veins
    shape : preset name
    """

    poly: np.ndarray
    centre: np.ndarray
    venation: str
    lobe_dirs: np.ndarray
    shape: str

    @property
    def xmin(self) -> float:
        return float(self.poly[:, 0].min())


def _resample(pts: np.ndarray, m: int) -> np.ndarray:
    """Closed polyline (K, 2) -> (m, 2) points uniform in arclength (first point kept)."""
    closed = np.vstack([pts, pts[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    t = np.linspace(0.0, s[-1], m, endpoint=False)
    return np.stack([np.interp(t, s, closed[:, 0]), np.interp(t, s, closed[:, 1])], axis=1)


def _jit(rng, x, rel):
    return x * float(np.exp(rng.normal(0.0, rel)))


def make_outline(shape: str, rng: np.random.Generator, serration: float = 0.0,
                 variation: float = 1.0, m: int | None = None) -> Outline:
    """A randomised outline of preset ``shape`` (per-leaf variation scaled by ``variation``).

    serration : tooth depth in blade lengths (0 = entire margin; 0.01-0.04 typical).
    """
    p = dict(SHAPES[shape])
    v = variation
    fam = p["family"]
    if m is None:
        m = 288 if (serration > 0 or fam == "palmate") else 192
    asym = rng.normal(0.0, 0.04 * v)  # left/right asymmetry
    if fam == "width":
        W = _jit(rng, p["W"], 0.10 * v)
        a = _jit(rng, p["a"], 0.10 * v)
        b = _jit(rng, p["b"], 0.10 * v)
        u = 0.5 - 0.5 * np.cos(np.linspace(0, np.pi, 400))  # dense at both ends
        w = u ** a * (1 - u) ** b
        tip = p.get("tip", 0.0)
        if tip:  # acuminate drip tip: pinch the last part
            w *= 1 - 0.5 * np.exp(-((1 - u) / max(tip * _jit(rng, 1.0, 0.2 * v), 1e-3)) ** 2) * (u > 0.5)
        w = W * w / w.max()
        lower = np.stack([u, -w * (1 - asym)], 1)
        upper = np.stack([u[::-1], (w * (1 + asym))[::-1]], 1)
        pts = np.vstack([lower, upper[1:-1]])
        centre = np.array([u[np.argmax(w)], 0.0])
        centre[0] = np.clip(centre[0], 0.3, 0.6)
        lobe_dirs = np.zeros(1)
    elif fam == "cordate":
        th = np.linspace(-np.pi, np.pi, 1200, endpoint=False)
        ax, ay = 1.0, _jit(rng, p["W"], 0.08 * v)
        r = ax * ay / np.sqrt((ay * np.cos(th)) ** 2 + (ax * np.sin(th)) ** 2)
        notch = np.clip(_jit(rng, p["notch"], 0.12 * v), 0.2, 0.8)
        r *= 1 - notch * np.exp(-((np.pi - np.abs(th)) / 0.35) ** 2)
        r *= 1 + _jit(rng, p["tip"], 0.2 * v) * np.exp(-(th / 0.25) ** 2)
        r *= 1 + asym * np.sin(th)
        pts = np.stack([r * np.cos(th), r * np.sin(th)], 1)
        centre = np.zeros(2)
        lobe_dirs = np.array([0.0, 1.1, -1.1, 2.2, -2.2])
    elif fam == "palmate":
        nl = p["lobes"]
        spread = _jit(rng, p["spread"], 0.06 * v)
        half = nl // 2
        angles = np.concatenate([[0.0], *[[spread * k / half, -spread * k / half] for k in range(1, half + 1)]])
        lens = [p["lengths"][0]] + [p["lengths"][k] for k in range(1, half + 1) for _ in (0, 1)]
        lens = np.array([_jit(rng, L, 0.08 * v) for L in lens])
        lens[0] = max(lens[0], lens[1:].max() * 1.02)
        angles = angles + rng.normal(0, 0.05 * v, len(angles)) * (np.arange(len(angles)) > 0)
        width = _jit(rng, spread / half * p["lobe_width"], 0.08 * v)
        sinus = np.clip(_jit(rng, p["sinus"], 0.1 * v), 0.15, 0.85)
        q = p["q"]
        th = np.linspace(-np.pi, np.pi, 2400, endpoint=False)
        bump = np.zeros_like(th)
        for ang, L in zip(angles, lens):
            d = np.abs(np.angle(np.exp(1j * (th - ang)))) / width
            f = np.clip(1 - d ** q, 0, None) + p["tip"] * np.exp(-(d / 0.1) ** 2)
            bump = np.maximum(bump, L * f)
        r = np.maximum(bump, sinus * lens[0] * (0.75 + 0.25 * np.cos(th)))
        # basal sinus: the petiole joins at theta = pi
        r *= 1 - p["base_notch"] * np.exp(-((np.pi - np.abs(th)) / 0.45) ** 2)
        pts = np.stack([r * np.cos(th), r * np.sin(th)], 1)
        centre = np.zeros(2)
        lobe_dirs = angles
    else:
        raise ValueError(f"unknown outline family {fam!r}")
    poly = _resample(pts, m)
    # normalise: base (rear-most point on the midrib) at the origin, apex at (1, 0)
    if fam == "width":
        base = np.array([0.0, 0.0])
        apex = np.array([1.0, 0.0])
    else:
        base = np.array([pts[np.argmin(np.abs(np.angle(np.exp(1j * (np.arctan2(pts[:, 1], pts[:, 0]) - np.pi))))), 0], 0.0])
        apex = np.array([pts[:, 0].max(), 0.0])
    L = apex[0] - base[0]
    poly = (poly - base) / L
    centre = (centre - base) / L
    if fam != "width":
        # the palmate/cordate centre sits at the lobe junction, move it a bit into the blade
        centre = centre + np.array([0.05, 0.0])
    if serration > 0:
        poly = _serrate(poly, centre, serration, rng)
    if _signed_area(poly) < 0:
        poly = poly[::-1].copy()
    return Outline(poly=poly, centre=centre, venation=p["venation"], lobe_dirs=lobe_dirs, shape=shape)


def _signed_area(poly):
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _serrate(poly, centre, depth, rng):
    """Saw teeth pointing towards the apex, radial about ``centre``, fading near the base."""
    closed = np.vstack([poly, poly[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])[:-1]
    spacing = float(np.clip(rng.normal(0.045, 0.008), 0.025, 0.07))
    phase = s / spacing + rng.uniform()
    # asymmetric tooth: slow rise, sharp drop; the sign makes teeth lean apex-ward on both sides
    side = np.sign(poly[:, 1] + 1e-9)
    fr = np.mod(phase * side, 1.0)
    tooth = fr ** 2 - 1.0 / 3.0
    d = poly - centre
    r = np.linalg.norm(d, axis=1, keepdims=True)
    fade = np.clip(np.linalg.norm(poly, axis=1) / 0.15, 0, 1)[:, None]
    return centre + d * (1 + depth * tooth[:, None] * fade / np.maximum(r, 0.05))


# ---------------------------------------------------------------------------------------------
# the curved sheet
# ---------------------------------------------------------------------------------------------

@dataclass
class LeafShapeParams:
    """Per-leaf bending parameters (radians / blade lengths)."""

    length: float = 0.15          # blade length base -> apex, metres
    fold: float = 0.15            # midrib V-fold: slope of each half (tan of the angle)
    cup: float = 0.3              # cross curvature (z = cup * y^2)
    droop: float = 0.6            # pitch change along the midrib (radians per blade length)
    droop2: float = 0.5           # extra, quadratic, towards the tip
    twist: float = 0.0            # roll about the midrib at the apex (radians)
    lateral: float = 0.0          # in-plane curvature of the midrib (y += lateral x^2)
    wave_amp: float = 0.0         # margin waviness (blade lengths)
    wave_freq: float = 6.0        # waves around the outline
    wave_phase: float = 0.0


@dataclass
class LeafSheet:
    """One blade: its GT mesh in the leaf local frame, plus per-vertex 2D coordinates.

    local : (V, 3) float64, leaf local frame, metres
    uv2d : (V, 2) float64, leaf 2D frame (blade lengths)
    radial : (V,) float64, 0 at the polar centre, 1 on the outline
    faces : (F, 3) int64, counter-clockwise seen from the upper side
    apex, base : (3,) float64, leaf local frame, metres
    """

    outline: Outline
    params: LeafShapeParams
    local: np.ndarray
    uv2d: np.ndarray
    radial: np.ndarray
    faces: np.ndarray
    apex: np.ndarray
    base: np.ndarray
    extra: dict = field(default_factory=dict)


def polar_mesh(outline: Outline, rings: int = 14):
    """Star mesh of an outline: (V, 2) points, (V,) radial parameter, (F, 3) faces (CCW)."""
    poly, c = outline.poly, outline.centre
    m = len(poly)
    t = (np.arange(1, rings + 1) / rings) ** 0.85  # slightly denser towards the margin
    pts = [c[None, :]]
    rad = [np.zeros(1)]
    for tk in t:
        pts.append(c + tk * (poly - c))
        rad.append(np.full(m, tk))
    pts = np.vstack(pts)
    rad = np.concatenate(rad)
    j = np.arange(m)
    jn = (j + 1) % m
    faces = [np.stack([np.zeros(m, int), 1 + j, 1 + jn], 1)]
    for k in range(rings - 1):
        a0, a1 = 1 + k * m, 1 + (k + 1) * m
        faces.append(np.stack([a0 + j, a1 + j, a1 + jn], 1))
        faces.append(np.stack([a0 + j, a1 + jn, a0 + jn], 1))
    return pts, rad, np.vstack(faces).astype(np.int64)


def _bend(x, y, z, prm: LeafShapeParams, xmin: float, xmax: float):
    """Map leaf-2D + normal offset (blade lengths) to the bent local frame (blade lengths)."""
    # twist about the midrib, growing from base to apex
    ang = prm.twist * np.clip(x, 0, None)
    y2 = y * np.cos(ang) - z * np.sin(ang)
    z2 = y * np.sin(ang) + z * np.cos(ang)
    y2 = y2 + prm.lateral * x * np.abs(x)
    # pitch along the midrib: phi(x) = -(droop x + droop2 x^2) for x > 0, linear behind the base
    g = np.linspace(min(xmin, 0.0) - 1e-3, max(xmax, 1.0) + 1e-3, 600)
    phi = -(prm.droop * g + prm.droop2 * np.clip(g, 0, None) ** 2)
    dx, dz = np.cos(phi), np.sin(phi)
    cx = np.concatenate([[0.0], np.cumsum(0.5 * (dx[1:] + dx[:-1]) * np.diff(g))])
    cz = np.concatenate([[0.0], np.cumsum(0.5 * (dz[1:] + dz[:-1]) * np.diff(g))])
    i0 = np.searchsorted(g, 0.0)
    cx -= np.interp(0.0, g, cx)
    cz -= np.interp(0.0, g, cz)
    del i0
    px, pz, ph = np.interp(x, g, cx), np.interp(x, g, cz), np.interp(x, g, phi)
    # normal of the bent midrib: (-sin phi, cos phi)
    X = px - z2 * np.sin(ph)
    Z = pz + z2 * np.cos(ph)
    return np.stack([X, y2, Z], 1)


def make_sheet(outline: Outline, prm: LeafShapeParams, rings: int = 14) -> LeafSheet:
    """Build the curved blade (GT mesh) of ``outline`` with bending ``prm``."""
    pts, rad, faces = polar_mesh(outline, rings)
    x, y = pts[:, 0], pts[:, 1]
    e = 0.015
    z = prm.fold * (np.sqrt(y * y + e * e) - e) + prm.cup * y * y
    if prm.wave_amp:
        m = len(outline.poly)
        ray = np.concatenate([[0], np.tile(np.arange(m), rings)])
        s = ray / m
        z = z + prm.wave_amp * rad ** 2 * np.sin(2 * np.pi * prm.wave_freq * s + prm.wave_phase)
    P = _bend(x, y, z, prm, outline.xmin, float(outline.poly[:, 0].max())) * prm.length
    apex_i = int(np.argmax(np.where(rad == 1.0, x - 10 * np.abs(y), -np.inf)))
    base = _bend(np.zeros(1), np.zeros(1), np.zeros(1), prm, outline.xmin, 1.0)[0] * prm.length
    return LeafSheet(outline=outline, params=prm, local=P, uv2d=pts, radial=rad, faces=faces,
                     apex=P[apex_i].copy(), base=base)


# ---------------------------------------------------------------------------------------------
# colour
# ---------------------------------------------------------------------------------------------

def vein_field(outline: Outline, xy: np.ndarray, rng_phase: float, n_secondary: int) -> np.ndarray:
    """(N,) vein intensity in [0, 1] at leaf 2D points ``xy`` (midrib, secondary/primary veins)."""
    x, y = xy[:, 0], xy[:, 1]
    if outline.venation == "parallel":
        w = np.maximum(np.abs(outline.poly[:, 1]).max(), 1e-3)
        mid = np.exp(-(y / (0.08 * w)) ** 2)
        stripes = 0.5 + 0.5 * np.cos(2 * np.pi * (y / w) * 4.5 + rng_phase)
        return np.clip(0.8 * mid + 0.35 * stripes ** 8, 0, 1)
    if outline.venation == "palmate":
        r = np.hypot(x, y) + 1e-9
        th = np.arctan2(y, x)
        v = np.zeros_like(x)
        for d in outline.lobe_dirs:
            dist = r * np.abs(np.sin(np.angle(np.exp(1j * (th - d))))) + (np.cos(th - d) < 0) * 1.0
            v = np.maximum(v, np.exp(-(dist / 0.01) ** 2) * np.exp(-r / 1.2))
        sec = 0.5 + 0.5 * np.cos(2 * np.pi * n_secondary * r + 3 * th + rng_phase)
        return np.clip(v + 0.25 * sec ** 12, 0, 1)
    mid = np.exp(-(y / 0.012) ** 2) * (x > -0.01) * (x < 0.97)
    k = 0.9  # secondary veins run outward and towards the apex
    phase = (x - k * np.abs(y)) * n_secondary + rng_phase
    d = np.abs(np.mod(phase, 1.0) - 0.5) / n_secondary
    sec = np.exp(-(d / 0.008) ** 2) * np.clip(np.abs(y) / 0.03, 0, 1)
    return np.clip(mid + 0.6 * sec, 0, 1)
