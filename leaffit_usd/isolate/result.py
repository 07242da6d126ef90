"""The result of plant isolation: one class per Gaussian, and the scene's frame cues."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

PLANT, GROUND, POT, SOIL, BACKGROUND, FLOATER = 0, 1, 2, 3, 4, 5
CLASS_NAMES = ("plant", "ground", "pot", "soil", "background", "floater")


@dataclass
class Isolation:
    """What :func:`leaffit_usd.isolate.isolate_plant` found (input frame, input units).

    classes : (N,) uint8, one per Gaussian of the cloud it ran on (cloud order; the cloud's
        ``file_index`` maps them to the file): PLANT 0, GROUND 1 (table / floor plane),
        POT 2, SOIL 3, BACKGROUND 4 (other objects, everything under the ground plane),
        FLOATER 5 (small isolated blobs, statistical outliers). ``CLASS_NAMES[c]`` names them.
    up : (3,) float64 unit vector or None; the up direction the scene shows: the ground plane's
        normal on the plant's side (``up_source`` "table") or the pot axis ("pot")
    up_source : "table" | "pot" | None
    root : (3,) float64 or None; the stem base at the soil (the lowest plant Gaussian near the
        pot axis), input frame
    root_index : int or None; index (cloud order) of the Gaussian at ``root``
    plane : (4,) float64 or None; ground plane ``n . x + d = 0`` with ``n = up`` when from the table
    pot : dict or None; ``center`` (3,) on the ground plane, ``axis`` (3,), ``radius_bottom``,
        ``radius_top``, ``height`` (input units), ``soil_height`` (above the plane)
    enabled : False when the stage was switched off (--keep-scene): every class is PLANT
    params : the parameters used (JSON-compatible)
    timings : seconds per step
    """

    classes: np.ndarray
    up: np.ndarray | None = None
    up_source: str | None = None
    root: np.ndarray | None = None
    root_index: int | None = None
    plane: np.ndarray | None = None
    pot: dict | None = None
    enabled: bool = True
    params: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)

    @property
    def plant_mask(self) -> np.ndarray:
        """(N,) bool, the Gaussians kept as the plant."""
        return np.asarray(self.classes) == PLANT

    def counts(self) -> dict[str, int]:
        """Gaussians per class name (every class present, zeros included)."""
        c = np.bincount(np.asarray(self.classes, np.int64), minlength=len(CLASS_NAMES))
        return {name: int(c[i]) for i, name in enumerate(CLASS_NAMES)}

    def removed(self) -> dict[str, int]:
        """Gaussians removed per class (every class but plant)."""
        return {k: v for k, v in self.counts().items() if k != "plant"}

    def to_dict(self) -> dict:
        """JSON-compatible summary (no per-Gaussian arrays)."""
        def vec(v):
            return None if v is None else [float(x) for x in np.asarray(v).ravel()]
        pot = None
        if self.pot is not None:
            pot = {k: (vec(v) if np.ndim(v) else float(v)) for k, v in self.pot.items()}
        return {"enabled": bool(self.enabled), "counts": self.counts(), "up": vec(self.up),
                "up_source": self.up_source, "root": vec(self.root),
                "plane": vec(self.plane), "pot": pot, "params": dict(self.params),
                "timings": {k: round(float(v), 4) for k, v in self.timings.items()}}

    def describe(self) -> str:
        """One line: what was removed, e.g. ``removed 41,200 of 98,000: ground 9,100, pot ...``."""
        rem = self.removed()
        total = sum(rem.values())
        parts = ", ".join(f"{k} {v:,}" for k, v in rem.items() if v)
        n = len(self.classes)
        return f"removed {total:,} of {n:,} Gaussians" + (f": {parts}" if parts else "")


def encode_classes(classes: np.ndarray) -> str:
    """(N,) uint8 -> zlib + base64 text (for JSON reports)."""
    import base64
    import zlib

    return base64.b64encode(zlib.compress(np.asarray(classes, np.uint8).tobytes(), 9)).decode("ascii")


def decode_classes(text: str) -> np.ndarray:
    """Inverse of :func:`encode_classes`: (N,) uint8."""
    import base64
    import zlib

    return np.frombuffer(zlib.decompress(base64.b64decode(text)), np.uint8).copy()
