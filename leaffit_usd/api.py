"""Python API for pipeline TDs: open a LeafFit stage, read and edit leaves, save.

Example::

    import leaffit_usd                       # registers the schema plug-in
    plant = leaffit_usd.open_plant("plant.usda")
    print(plant.n_leaves, plant.K)
    q = plant.control_points(3)              # (K, 3) leaf 3's MLS targets, instance local frame
    plant.set_control_point(3, 0, q[0] + [0, 0, 0.01])   # lift its first control point
    plant.set_leaf_transform(3, scale=1.2 * plant.leaf(3).scale)
    plant.set_texture("front", "painted_front.png")      # swap the template's front texture
    verts = plant.leaf_vertices(3)           # (V, 3) deformed leaf, asset frame
    plant.save()                             # writes the stage and refreshes the baked payload
    plant.export("edited.usdz")              # or a new complete asset in any format

Every setter writes straight to the stage (``plant.stage``, a ``pxr.Usd.Stage``), so the pxr API
and this one can be mixed. ``.usdz`` packages are read-only here: ``export`` them instead.
Frames: control points are in the instance local frame (template units, before the instance
scale); positions/vertices in the asset (stage) frame; quaternions (w, x, y, z).
"""
from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from leaffit_usd.errors import InputFileError, ParameterError, UserError
from leaffit_usd.usd import schema as S
from leaffit_usd.usd.vt import quat_arrays, vec3f_array


@dataclass(frozen=True)
class Leaf:
    """One leaf instance (a snapshot; use the Plant's setters to change it).

    index : row j in the PointInstancer; label : its segmentation label
    position : (3,) asset frame; orientation : (4,) (w, x, y, z); scale : float (uniform)
    control_points : (K, 3) instance local frame (template units)
    """

    index: int
    label: int
    position: np.ndarray
    orientation: np.ndarray
    scale: float
    control_points: np.ndarray


class Plant:
    """A LeafFit plant stage opened for scripting (see the module docstring)."""

    def __init__(self, path):
        from leaffit_usd.usd.reader import find_instancer, open_stage, read_stage_object

        self.path = Path(path)
        self.stage = open_stage(self.path)
        self._inst = find_instancer(self.stage)
        if self._inst is None:
            raise InputFileError(self.path, "not a LeafFit plant")
        self._asset = read_stage_object(self.stage, self.path)
        self._dirty_geometry = False

    # ---- reading ----------------------------------------------------------------------------
    @property
    def asset(self):
        """The current state as a PlantAsset (re-read from the stage after edits)."""
        if self._asset is None:
            from leaffit_usd.usd.reader import read_stage_object
            self._asset = read_stage_object(self.stage, self.path)
        return self._asset

    @property
    def n_leaves(self) -> int:
        return self.asset.n_leaves

    @property
    def K(self) -> int:
        return int(self.asset.template_controls.shape[0])

    @property
    def template_points(self) -> np.ndarray:
        """(V, 3) float32 template mesh vertices, template local frame."""
        return self.asset.template_points

    @property
    def template_faces(self) -> np.ndarray:
        return self.asset.template_faces

    @property
    def template_controls(self) -> np.ndarray:
        """(K, 3) float32 MLS source control points p, template local frame."""
        return self.asset.template_controls

    def control_points(self, j: int) -> np.ndarray:
        """(K, 3) float32 target control points of leaf j, instance local frame."""
        return self.asset.targets[self._check_leaf(j)].copy()

    def leaf(self, j: int) -> Leaf:
        a = self.asset
        j = self._check_leaf(j)
        return Leaf(j, int(a.leaf_labels[j]), a.positions[j].copy(), a.orientations[j].copy(),
                    float(a.scales[j].mean()), a.targets[j].copy())

    @property
    def leaves(self) -> list[Leaf]:
        return [self.leaf(j) for j in range(self.n_leaves)]

    @property
    def texture_paths(self) -> tuple[str, str]:
        """(front, back) texture paths as authored (relative to the stage)."""
        return self.asset.front_texture, self.asset.back_texture

    def leaf_vertices(self, j: int | None = None, frame: str = "asset") -> np.ndarray:
        """Deformed leaf vertices: (V, 3) for leaf j, or (L, V, 3) for all; 'asset' or 'input' frame."""
        from leaffit_usd.runtime.evaluator import asset_leaves

        v = asset_leaves(self.asset)
        if frame == "input":
            m = self.asset.asset_to_input
            v = v @ m[:3, :3].T + m[:3, 3]
        elif frame != "asset":
            raise ParameterError("frame", "'asset' or 'input'", frame)
        return v if j is None else v[self._check_leaf(j)]

    # ---- writing ----------------------------------------------------------------------------
    def set_control_points(self, j: int, q) -> None:
        """Replace leaf j's K target control points ((K, 3), instance local frame)."""
        j = self._check_leaf(j)
        q = np.asarray(q, np.float32)
        if q.shape != (self.K, 3) or not np.isfinite(q).all():
            raise ParameterError("q", f"a finite ({self.K}, 3) array", q.shape)
        targets = self.asset.targets.copy()
        targets[j] = q
        attr = self._inst.GetAttribute(str(self._inst.GetAttribute(S.ATTR_TARGETS_PRIMVAR).Get()
                                           or S.TARGETS_PRIMVAR))
        attr.Set(vec3f_array(targets))
        self._changed()

    def set_control_point(self, j: int, k: int, xyz) -> None:
        """Move control point k of leaf j to xyz ((3,), instance local frame)."""
        if not 0 <= int(k) < self.K:
            raise ParameterError("k", f"a control point index in 0..{self.K - 1}", k)
        q = self.control_points(j)
        q[int(k)] = np.asarray(xyz, np.float32).reshape(3)
        self.set_control_points(j, q)

    def set_leaf_transform(self, j: int, position=None, orientation=None, scale=None) -> None:
        """Change leaf j's rigid placement (asset frame; orientation (w, x, y, z); uniform scale)."""
        from pxr import UsdGeom

        j = self._check_leaf(j)
        a = self.asset
        inst = UsdGeom.PointInstancer(self._inst)
        if position is not None:
            pos = a.positions.copy()
            pos[j] = np.asarray(position, np.float32).reshape(3)
            inst.GetPositionsAttr().Set(vec3f_array(pos))
        if orientation is not None:
            q = a.orientations.copy()
            o = np.asarray(orientation, np.float64).reshape(4)
            if not np.isfinite(o).all() or np.linalg.norm(o) < 1e-12:
                raise ParameterError("orientation", "a non-zero quaternion (w, x, y, z)", orientation)
            q[j] = o / np.linalg.norm(o)
            qh, qf = quat_arrays(q)
            inst.GetOrientationsAttr().Set(qh)
            inst.GetOrientationsfAttr().Set(qf)
        if scale is not None:
            s = float(scale)
            if not (np.isfinite(s) and s > 0):
                raise ParameterError("scale", "a positive number", scale)
            sc = a.scales.copy()
            sc[j] = s
            inst.GetScalesAttr().Set(vec3f_array(sc))
        self._changed()

    def set_texture(self, side: str, image) -> str:
        """Swap the template's front or back texture.

        image : path of an image file (copied beside the stage under textures/), or an
        (H, W, 3|4) uint8 array (written as PNG there). Returns the new relative path.
        """
        from pxr import Sdf, Usd, UsdShade

        if side not in ("front", "back"):
            raise ParameterError("side", "'front' or 'back'", side)
        self._check_writable()
        name = f"{self.path.stem}.{side}"
        tex_dir = self.path.parent / "textures"
        tex_dir.mkdir(parents=True, exist_ok=True)
        if isinstance(image, (str, Path)):
            src = Path(image)
            if not src.is_file():
                raise InputFileError(src, "no such file")
            ext = src.suffix.lower()
            if ext not in (".png", ".jpg", ".jpeg", ".exr"):
                raise InputFileError(src, "texture must be .png, .jpg or .exr")
            rel = f"textures/{name}.edited{ext}"
            shutil.copyfile(src, self.path.parent / rel)
        else:
            from leaffit_usd.image_io import write_image
            rel = f"textures/{name}.edited.png"
            write_image(self.path.parent / rel, np.asarray(image))
        root = self.stage.GetDefaultPrim()
        mat = self.stage.GetPrimAtPath(root.GetPath().AppendPath(f"Looks/Leaf{side.capitalize()}"))
        if not mat:
            raise InputFileError(self.path, f"no material Looks/Leaf{side.capitalize()}")
        done = False
        for prim in Usd.PrimRange(mat):
            sh = UsdShade.Shader(prim)
            if sh and sh.GetIdAttr().Get() == "UsdUVTexture":
                sh.GetInput("file").Set(Sdf.AssetPath("./" + rel))
                done = True
        if not done:
            raise InputFileError(self.path, f"material {mat.GetPath()} has no texture to swap")
        self._asset = None
        return "./" + rel

    def save(self) -> Path:
        """Save the edits in place (.usda/.usdc) and refresh the baked-leaves payload."""
        from leaffit_usd.runtime.evaluator import asset_leaves
        from leaffit_usd.usd.writer import write_baked_layer

        self._check_writable()
        self.stage.GetRootLayer().Save()
        payload = self._baked_payload_path()
        if payload is not None and self._dirty_geometry:
            a = self.asset
            write_baked_layer(payload, a, asset_leaves(a, separate_sheets=True),
                              [asset_leaves(a.at_lod(k), separate_sheets=True) for k in range(1, len(a.lods) + 1)])
        self._dirty_geometry = False
        return self.path

    def export(self, path, options=None):
        """Write the current plant as a new, complete asset (.usda/.usdc/.usdz) with
        ``usd.writer.write_stage`` (textures re-read from the current files). Returns WriteResult."""
        from leaffit_usd.runtime.evaluator import asset_leaves
        from leaffit_usd.usd.reader import has_mask, read_texture
        from leaffit_usd.usd.writer import LeafTextures, WriteOptions, write_stage

        a = self.asset
        front, back = read_texture(self.stage, a.front_texture), read_texture(self.stage, a.back_texture)
        textures = LeafTextures(front, back) if front is not None and back is not None else None
        if options is None:
            fmt = "png" if Path(a.front_texture).suffix.lower() == ".png" else \
                "jpg+mask" if has_mask(self.stage, a.front_texture) else "jpg"
            options = WriteOptions(texture_format=fmt, texture_max_size=16384)
        return write_stage(path, a, textures, options, leaves=asset_leaves(a, separate_sheets=True),
                           lod_leaves=[asset_leaves(a.at_lod(k), separate_sheets=True)
                                       for k in range(1, len(a.lods) + 1)])

    # ---- helpers ------------------------------------------------------------------------------
    def _baked_payload_path(self):
        """The baked payload file the 'baked' variant loads (None if the stage has none)."""
        root = self.stage.GetDefaultPrim()
        # the root layer, or the variants sublayer beside a .usda root (usd.writer)
        for layer in self.stage.GetLayerStack(includeSessionLayers=False):
            prim_spec = layer.GetPrimAtPath(root.GetPath())
            for spec in (prim_spec.variantSets.values() if prim_spec else []):
                for variant in spec.variants.values():
                    baked = variant.primSpec.nameChildren.get("BakedLeaves")
                    if baked is not None:
                        for ref in baked.payloadList.GetAddedOrExplicitItems():
                            return Path(layer.ComputeAbsolutePath(ref.assetPath))
        return None

    def _check_leaf(self, j) -> int:
        if not isinstance(j, (int, np.integer)) or not 0 <= int(j) < self.asset.n_leaves:
            raise ParameterError("leaf", f"an index in 0..{self.asset.n_leaves - 1}", j)
        return int(j)

    def _check_writable(self):
        if self.path.suffix.lower() == ".usdz":
            raise UserError(f"{self.path}: .usdz packages are read-only here; save(path) to a .usda or .usdc")

    def _changed(self):
        self._asset = None
        self._dirty_geometry = True


def open_plant(path) -> Plant:
    """Open a LeafFit stage (.usda/.usdc/.usdz) for reading and editing. Raises InputFileError."""
    return Plant(path)
