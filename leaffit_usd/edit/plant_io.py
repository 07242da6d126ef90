"""Read a LeafFit stage with its two leaf textures, and write an edited copy (edits never touch
the input unless asked to, and then atomically)."""
from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from leaffit_usd.errors import InputFileError, ParameterError
from leaffit_usd.image_io import read_image
from leaffit_usd.usd.asset import PlantAsset


@dataclass
class EditablePlant:
    """A stage's content. front, back : (H, W, 4) float32 RGBA images; texture_format : 'jpg+mask'|'jpg'|'png'."""

    asset: PlantAsset
    front: np.ndarray
    back: np.ndarray
    texture_format: str


def _read_asset_bytes(stage_path: Path, asset_path: str) -> bytes:
    """Bytes of an asset path authored in the stage's root layer (works inside .usdz too)."""
    from pxr import Ar, Sdf

    layer = Sdf.Layer.FindOrOpen(str(stage_path))
    resolved = Ar.GetResolver().Resolve(layer.ComputeAbsolutePath(asset_path)) if layer else None
    if not resolved:
        raise InputFileError(stage_path, f"texture {asset_path!r} cannot be found")
    asset = Ar.GetResolver().OpenAsset(resolved)
    if asset is None:
        raise InputFileError(stage_path, f"texture {asset_path!r} cannot be opened")
    return bytes(asset.GetBuffer())


def _texture(stage_path: Path, asset_path: str) -> np.ndarray:
    """(H, W, 4) float32 RGBA of a leaf texture; a ``jpg+mask`` texture's alpha from its mask."""
    if not asset_path:
        raise InputFileError(stage_path, "the leaf material has no texture to edit")
    img = _image_asset(stage_path, asset_path)
    mask = _mask(stage_path, asset_path)
    if mask is not None and mask.shape[:2] == img.shape[:2]:
        img = img.copy()
        img[..., 3] = mask[..., 0]
    return img


def _mask(stage_path: Path, asset_path: str):
    """The ``jpg+mask`` alpha mask beside a colour texture (``usd.writer.mask_path``), or None."""
    from leaffit_usd.usd.writer import mask_path

    if asset_path.lower().endswith(".png"):
        return None
    try:
        return _image_asset(stage_path, mask_path(asset_path))
    except InputFileError:
        return None


def _image_asset(stage_path: Path, asset_path: str) -> np.ndarray:
    suffix = os.path.splitext(asset_path)[1] or ".png"
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d) / f"texture{suffix}"
        tmp.write_bytes(_read_asset_bytes(stage_path, asset_path))
        return read_image(tmp)


def load_plant(path) -> EditablePlant:
    """Read a LeafFit stage (.usda/.usdc/.usdz) and its front/back textures."""
    from leaffit_usd.usd.reader import read_stage

    path = Path(path)
    asset = read_stage(path)
    front = _texture(path, asset.front_texture)
    back = _texture(path, asset.back_texture) if asset.back_texture else front.copy()
    fmt = "png" if asset.front_texture.lower().endswith(".png") else \
        "jpg+mask" if _mask(path, asset.front_texture) is not None else "jpg"
    return EditablePlant(asset, front, back, fmt)


def save_plant(plant: EditablePlant, output, source=None, in_place: bool = False):
    """Write ``plant`` as a new stage at ``output`` (atomic). Refuses to overwrite ``source``
    unless ``in_place``. Returns the writer's WriteResult."""
    from leaffit_usd.runtime.evaluator import asset_leaves
    from leaffit_usd.usd.writer import LeafTextures, WriteOptions, write_stage

    output = Path(output)
    if source is not None and not in_place and output.exists() and \
            output.resolve() == Path(source).resolve():
        raise ParameterError("-o/--output", "a new file (or --in-place to replace the input)", str(output))
    to8 = lambda im: (np.clip(im, 0, 1) * 255 + 0.5).astype(np.uint8)  # noqa: E731
    tex = LeafTextures(front=to8(plant.front), back=to8(plant.back))
    size = max(plant.front.shape[:2])
    return write_stage(output, plant.asset, tex, WriteOptions(texture_format=plant.texture_format,
                                                              texture_max_size=max(16, size)),
                       leaves=asset_leaves(plant.asset, separate_sheets=True))
