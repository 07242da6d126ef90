"""The template's two texture images: float -> 8-bit, and the front/back files on disk."""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.image_io import write_image
from leaffit_usd.mesh.result import TemplateMesh

FORMATS = ("png", "exr")  # write_textures: lossless (8-bit sRGB or half-float linear)


def to_u8(tex: np.ndarray) -> np.ndarray:
    return np.clip(np.round(tex * 255.0), 0, 255).astype(np.uint8)

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
