"""Template leaf mesh extraction, UVs and two-sided texture bake, stem cylinders.

Entry points: :func:`leaffit_usd.mesh.template.build_template_mesh` (+ ``params.MeshParams``,
``texture_files.write_textures``) and :func:`leaffit_usd.mesh.stem.build_stem` (+ ``StemParams``).
"""
from leaffit_usd.mesh.result import Stem, TemplateMesh
from leaffit_usd.mesh.stem import StemParams, build_stem
from leaffit_usd.mesh.params import MeshParams
from leaffit_usd.mesh.template import build_template_mesh
from leaffit_usd.mesh.texture_files import write_textures

__all__ = ["TemplateMesh", "Stem", "MeshParams", "build_template_mesh", "write_textures",
           "StemParams", "build_stem"]
