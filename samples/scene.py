"""Capture-like surroundings for a generated plant: what a real 3DGS capture keeps around a
potted plant (``PlantSpec(scene=True)``, ``python -m samples.generate --scene``).

Canonical frame (metres, root = stem base at the origin, +Z up). The scene is:

* a **pot**: a tapered round pot (terracotta, grey plastic or white ceramic) whose rim stands
  1-4 cm above the soil, outer wall, the inner wall above the soil and a rounded rim lip;
* **soil**: a bumpy disk a few mm below the stem base filling the pot, with pebbles;
* a **table** top (wood grain) under the pot, rectangular, the pot off its centre;
* **clutter** on the table (boxes and mugs, clear of the plant's footprint), a **back wall**
  rising from the table's far edge, a few far blobs of large Gaussians (the room);
* scene **floaters** spread over the whole captured volume.

Ground-truth class of each Gaussian (``SCENE_CLASSES`` order, the same codes as
``leaffit_usd.isolate``): 0 plant, 1 ground (table), 2 pot, 3 soil, 4 background (clutter, wall,
room), 5 floater.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SCENE_CLASSES = ("plant", "ground", "pot", "soil", "background", "floater")
GROUND, POT, SOIL, BACKGROUND, FLOATER = 1, 2, 3, 4, 5

_POT_COLOURS = {"terracotta": (0.70, 0.38, 0.22), "plastic": (0.18, 0.18, 0.19),
                "ceramic": (0.86, 0.85, 0.82)}


def frame_from_normal(nrm: np.ndarray) -> np.ndarray:
    """(n, 3) unit normals -> (n, 3, 3) rotations whose third column is the normal."""
    a = np.where(np.abs(nrm[:, 2:3]) < 0.9, [[0, 0, 1.0]], [[1.0, 0, 0]])
    e1 = np.cross(nrm, a)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return np.stack([e1, np.cross(nrm, e1), nrm], axis=2)


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _flat(pos, nrm, spacing, rng, thin=0.12):
    """Flat Gaussians on a surface: scales (n, 3) (two in-plane ~ spacing, one thin), R."""
    n = len(pos)
    s1 = spacing * 0.6 * np.exp(rng.normal(0, 0.25, n))
    s2 = s1 * rng.uniform(0.5, 1.0, n)
    return np.stack([s1, s2, thin * np.sqrt(s1 * s2)], 1), frame_from_normal(nrm)


WALL = 0.012  # pot wall thickness, m


@dataclass(frozen=True)
class PotGeometry:
    """A tapered round pot standing on z = ``z_bot`` around the +Z axis (canonical frame, metres).

    r_top, r_bot : outer radius at the rim / the bottom; height : rim above the bottom;
    z_soil : the soil surface; z_rim : the rim's top (``z_bot = z_rim - height``)."""

    r_top: float
    r_bot: float
    height: float
    z_soil: float
    z_rim: float

    @property
    def z_bot(self) -> float:
        return self.z_rim - self.height

    def radius_at(self, z):
        """Outer radius at height z (m)."""
        return self.r_bot + (self.r_top - self.r_bot) * (z - self.z_bot) / self.height


def pot_gaussians(geo: PotGeometry, m: int, pot_col, rng: np.random.Generator, opacity,
                  shares=(0.75, 0.12)):
    """Gaussians of the pot: outer wall, inner wall above the soil and the rounded rim lip.

    m : how many; pot_col : (3,) RGB; opacity : callable m -> (m,) opacities (drawn from
    ``rng``); shares : outer and inner wall's shares of m (the lip gets the rest).
    Returns three (pos (k, 3), scales (k, 3), R (k, 3, 3), colour (k, 3), opacity (k,), POT).
    """
    r_top, r_bot, ph = geo.r_top, geo.r_bot, geo.height
    z_soil, z_rim, z_bot = geo.z_soil, geo.z_rim, geo.z_bot
    out = []
    m_out, m_in = int(shares[0] * m), int(shares[1] * m)
    m_rim = m - m_out - m_in
    z = rng.uniform(z_bot, z_rim, m_out)
    r = r_bot + (r_top - r_bot) * (z - z_bot) / ph
    a = rng.uniform(0, 2 * np.pi, m_out)
    pos = np.stack([r * np.cos(a), r * np.sin(a), z], 1)
    slope = (r_bot - r_top) / ph
    nrm = np.stack([np.cos(a), np.sin(a), np.full(m_out, -slope)], 1)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    area = np.pi * (r_top + r_bot) * ph
    sc, R = _flat(pos, nrm, np.sqrt(area / m_out), rng)
    shade = (0.8 + 0.2 * np.cos(a - 0.7))[:, None]
    out.append((pos + nrm * rng.normal(0, 0.0005, (m_out, 1)), sc, R,
                pot_col * shade * rng.uniform(0.9, 1.08, (m_out, 1)), opacity(m_out), POT))
    t = rng.uniform(0, 1, m_in)
    z = z_soil + t * (z_rim - z_soil)
    r = r_bot + (r_top - r_bot) * (z - z_bot) / ph - WALL
    a = rng.uniform(0, 2 * np.pi, m_in)
    pos = np.stack([r * np.cos(a), r * np.sin(a), z], 1)
    nrm = -np.stack([np.cos(a), np.sin(a), np.zeros(m_in)], 1)
    sc, R = _flat(pos, nrm, np.sqrt(2 * np.pi * r_top * (z_rim - z_soil) / m_in), rng)
    out.append((pos, sc, R, pot_col * 0.7 * rng.uniform(0.9, 1.1, (m_in, 1)), opacity(m_in), POT))
    a = rng.uniform(0, 2 * np.pi, m_rim)
    b = rng.uniform(-np.pi / 2, np.pi, m_rim)  # around the lip's half-torus
    lip = 0.5 * WALL + 0.003
    rr = r_top - 0.5 * WALL + lip * np.cos(b)
    pos = np.stack([rr * np.cos(a), rr * np.sin(a), z_rim + lip * np.sin(b)], 1)
    nrm = np.stack([np.cos(b) * np.cos(a), np.cos(b) * np.sin(a), np.sin(b)], 1)
    sc, R = _flat(pos, nrm, np.sqrt(2 * np.pi * r_top * np.pi * lip / m_rim), rng)
    out.append((pos, sc, R, pot_col * rng.uniform(0.95, 1.15, (m_rim, 1)), opacity(m_rim), POT))
    return out


def _soil_colour_ideal(m: int, rng: np.random.Generator) -> np.ndarray:
    """Brown soil with 6 % light pebbles, (m, 3) RGB."""
    col = np.array([0.22, 0.15, 0.10]) * rng.uniform(0.6, 1.3, (m, 1))
    pebble = rng.uniform(size=m) < 0.06
    col[pebble] = np.array([0.6, 0.58, 0.52]) * rng.uniform(0.8, 1.1, (int(pebble.sum()), 1))
    return col


def soil_gaussians(geo: PotGeometry, m: int, rng: np.random.Generator, opacity,
                   colour=_soil_colour_ideal):
    """Gaussians of the soil: a bumpy disk filling the pot at ``geo.z_soil``.

    colour : callable (m, rng) -> (m, 3) RGB. Returns (pos, scales, R, colour, opacity, SOIL).
    """
    r_in = geo.radius_at(geo.z_soil) - WALL
    rr = r_in * np.sqrt(rng.uniform(0, 1, m))
    a = rng.uniform(0, 2 * np.pi, m)
    x, y = rr * np.cos(a), rr * np.sin(a)
    k = rng.normal(0, 1, (5, 2)) * 25.0
    ph_ = rng.uniform(0, 2 * np.pi, 5)
    bump = 0.0025 * np.sum(np.sin(np.outer(x, k[:, 0]) + np.outer(y, k[:, 1]) + ph_), axis=1) / np.sqrt(5)
    pos = np.stack([x, y, geo.z_soil + bump + rng.normal(0, 0.0008, m)], 1)
    nrm = np.c_[rng.normal(0, 0.15, (m, 2)), np.ones(m)]
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    sc, R = _flat(pos, nrm, np.sqrt(np.pi * r_in ** 2 / m), rng, thin=0.3)
    return pos, sc, R, colour(m, rng), opacity(m), SOIL


def make_scene(plant_pos: np.ndarray, height: float, n: int, rng: np.random.Generator,
               pot: str | None = None):
    """Gaussians of the surroundings of a plant (canonical frame).

    plant_pos : (M, 3) the plant's Gaussians (canonical, metres, root at 0, +Z up)
    height : plant height (m); n : about how many scene Gaussians to make
    pot : "terracotta" | "plastic" | "ceramic", None = drawn from ``rng``
    Returns (pos (n', 3), scales (n', 3), R (n', 3, 3), colour (n', 3), opacity (n',),
    classes (n',) int32 in 1..5) and a dict describing the scene (pot radii, heights, table).
    """
    H = float(height)
    r_top = float(np.clip(rng.uniform(0.15, 0.25) * H, 0.05, 0.2))
    r_bot = r_top * rng.uniform(0.7, 0.9)
    ph = r_top * rng.uniform(1.2, 1.8)
    z_soil = -rng.uniform(0.003, 0.008)
    z_rim = z_soil + rng.uniform(0.01, 0.04)
    z_bot = z_rim - ph
    kind = ("terracotta", "plastic", "ceramic")[int(rng.integers(3))]
    kind = pot or kind  # drawn either way: the same stream whether or not the pot is chosen
    pot_col = np.array(_POT_COLOURS[kind])
    # horizontal reach of the plant (clutter stays clear of it)
    reach = float(np.quantile(np.hypot(plant_pos[:, 0], plant_pos[:, 1]), 0.98))
    # table: rectangle with the pot off centre, big enough for clutter beyond the plant's reach
    hx = max(reach, 2.5 * r_top) + rng.uniform(0.15, 0.4) * H
    hy = max(reach, 2.5 * r_top) + rng.uniform(0.1, 0.3) * H
    cx, cy = rng.uniform(-0.3, 0.3) * hx, rng.uniform(-0.3, 0.3) * hy
    budgets = dict(table=0.32, pot=0.2, soil=0.12, clutter=0.16, wall=0.12, room=0.05, floater=0.03)
    cnt = {k: max(50, int(v * n)) for k, v in budgets.items()}
    parts = []  # (pos, scales, R, colour, opacity, class)

    def add(pos, sc, R, col, op, cls):
        parts.append((pos, sc, R, np.clip(col, 0.01, 0.99), op, np.full(len(pos), cls, np.int32)))

    def opaque(m):
        return np.where(rng.uniform(size=m) < 0.92, rng.uniform(0.8, 0.999, m), rng.uniform(0.2, 0.8, m))

    # ---- pot (outer wall, inner wall above the soil, rim lip) and soil ---------------------------
    geo = PotGeometry(r_top, r_bot, ph, z_soil, z_rim)
    for part in pot_gaussians(geo, cnt["pot"], pot_col, rng, opaque):
        add(*part)
    add(*soil_gaussians(geo, cnt["soil"], rng, opaque))

    # ---- table top: wood grain, the pot's footprint left out ---------------------------------
    m = cnt["table"]
    x = cx + rng.uniform(-hx, hx, m)
    y = cy + rng.uniform(-hy, hy, m)
    keep = np.hypot(x, y) > r_bot
    x, y = x[keep], y[keep]
    m = len(x)
    pos = np.stack([x, y, z_bot + rng.normal(0, 0.0005, m)], 1)
    nrm = np.tile([0, 0, 1.0], (m, 1))
    sc, R = _flat(pos, nrm, np.sqrt(4 * hx * hy / m), rng)
    grain = 0.5 + 0.5 * np.sin(y * 90.0 + 2.0 * np.sin(x * 7.0))
    col = np.array([0.52, 0.36, 0.22])[None] * (0.8 + 0.3 * grain)[:, None]
    add(pos, sc, R, col * rng.uniform(0.95, 1.05, (m, 1)), opaque(m), GROUND)

    # ---- clutter on the table: boxes and mugs clear of the plant ------------------------------
    m_all = cnt["clutter"]
    n_obj = int(rng.integers(2, 5))
    objs = []
    for j in range(n_obj):
        for _ in range(50):
            ox, oy = cx + rng.uniform(-hx, hx) * 0.85, cy + rng.uniform(-hy, hy) * 0.85
            size = rng.uniform(0.04, 0.12) * max(H, 0.3)
            if np.hypot(ox, oy) > reach + size + 0.05 * H:
                break
        else:
            continue
        objs.append((ox, oy, size, "box" if rng.uniform() < 0.5 else "mug"))
    for ox, oy, size, what in objs:
        m = m_all // max(len(objs), 1)
        h = size * rng.uniform(0.8, 1.8)
        if what == "mug":
            a = rng.uniform(0, 2 * np.pi, m)
            z = rng.uniform(0, h, m)
            top = rng.uniform(size=m) < 0.15
            rr = np.where(top, size * np.sqrt(rng.uniform(size=m)), size)
            z = np.where(top, h, z)
            pos = np.stack([ox + rr * np.cos(a), oy + rr * np.sin(a), z_bot + z], 1)
            nrm = np.where(top[:, None], [[0, 0, 1.0]], np.stack([np.cos(a), np.sin(a), np.zeros(m)], 1))
        else:
            face = rng.integers(0, 5, m)  # +x -x +y -y top
            u, v = rng.uniform(-1, 1, m), rng.uniform(0, 1, m)
            lx, ly = size, size * rng.uniform(0.6, 1.4)
            px = np.select([face == 0, face == 1], [lx, -lx], u * lx)
            py = np.select([face == 2, face == 3], [ly, -ly], np.where(face < 2, u * ly, rng.uniform(-1, 1, m) * ly))
            pz = np.where(face == 4, h, v * h)
            pos = np.stack([ox + px, oy + py, z_bot + pz], 1)
            nrm = np.zeros((m, 3))
            nrm[face == 0, 0], nrm[face == 1, 0], nrm[face == 2, 1], nrm[face == 3, 1] = 1, -1, 1, -1
            nrm[face == 4, 2] = 1
        sc, R = _flat(pos, nrm, np.sqrt(6 * size * h / max(m, 1)), rng)
        col = rng.uniform(0.1, 0.9, 3)[None] * rng.uniform(0.85, 1.1, (m, 1))
        add(pos, sc, R, col, opaque(m), BACKGROUND)

    # ---- back wall from the table's far edge, and the room ---------------------------------------
    m = cnt["wall"]
    y_wall = cy + hy + rng.uniform(0.0, 0.05)
    x = cx + rng.uniform(-1.3 * hx, 1.3 * hx, m)
    z = z_bot + rng.uniform(0.0, 1.6 * H, m)
    pos = np.stack([x, np.full(m, y_wall) + rng.normal(0, 0.001, m), z], 1)
    nrm = np.tile([0, -1.0, 0], (m, 1))
    sc, R = _flat(pos, nrm, np.sqrt(2.6 * hx * 1.6 * H / m), rng)
    col = np.array([0.8, 0.78, 0.72]) * (0.85 + 0.1 * np.sin(z * 5.0))[:, None]
    add(pos, sc, R, col, rng.uniform(0.3, 0.95, m), BACKGROUND)
    m = cnt["room"]
    blobs = []
    for _ in range(int(rng.integers(3, 7))):
        c = rng.normal(size=3)
        c[1] = -abs(c[1])  # in front of the wall
        c = c / np.linalg.norm(c) * rng.uniform(1.5, 3.0) * H
        blobs.append(c + rng.normal(0, rng.uniform(0.05, 0.2) * H, (m // 5 + 1, 3)))
    pos = np.concatenate(blobs)[:m]
    mm = len(pos)
    sc = np.exp(rng.normal(np.log(0.02 * H), 0.4, (mm, 3)))
    R = frame_from_normal(unit(rng.normal(size=(mm, 3))))
    add(pos, sc, R, rng.uniform(0.1, 0.9, (mm, 3)), rng.uniform(0.3, 0.9, mm), BACKGROUND)

    # ---- floaters over the captured volume -------------------------------------------------------
    m = cnt["floater"]
    lo = np.array([cx - 1.3 * hx, cy - 1.3 * hy, z_bot])
    hi = np.array([cx + 1.3 * hx, y_wall, z_bot + 1.8 * H])
    pos = lo + rng.uniform(0, 1, (m, 3)) * (hi - lo)
    sc = np.exp(rng.normal(np.log(0.004), 0.6, (m, 3)))
    R = frame_from_normal(unit(rng.normal(size=(m, 3))))
    add(pos, sc, R, rng.uniform(0.2, 0.8, (m, 3)), rng.uniform(0.02, 0.5, m), FLOATER)

    cat = [np.concatenate([p[i] for p in parts]) for i in range(6)]
    info = {"pot": kind, "pot_radius_top_m": r_top, "pot_radius_bottom_m": r_bot,
            "pot_height_m": ph, "rim_z_m": z_rim, "soil_z_m": z_soil, "table_z_m": z_bot,
            "table_half_m": [hx, hy], "table_centre_m": [cx, cy], "clutter": len(objs),
            "wall_y_m": y_wall}
    return (*cat, info)
