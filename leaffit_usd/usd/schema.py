"""Registration of the LeafFit codeless USD schema (``leaffit_usd/schemas/``).

``import leaffit_usd`` calls :func:`register` (or, when ``pxr`` is not loaded yet,
:func:`announce`; both in :mod:`leaffit_usd.schema_plugin`) before anything else can touch USD's schema registry: a plug-in registered
after ``Usd.SchemaRegistry`` was first used is ignored silently (``ApplyAPI`` then raises). Tools that do not import ``leaffit_usd`` can load the schema with

    export PXR_PLUGINPATH_NAME=$(python -c "import leaffit_usd.usd.schema as s; print(s.SCHEMA_DIR)")

Readers without the plug-in still open our files and read every value: the writer authors each
deformer attribute explicitly instead of relying on the schema's fallbacks.

Regenerate ``generatedSchema.usda``/``plugInfo.json`` after editing ``schema.usda`` with
``python -m leaffit_usd.usd.schema --regenerate``.
"""
from __future__ import annotations

import json
import logging
import subprocess
import sys
from pathlib import Path

from leaffit_usd.schema_plugin import SCHEMA_DIR, announce, register  # noqa: F401 (this module's API)

API_NAME = "LeafFitMLSDeformerAPI"

# Attribute names of the deformer API (kept in one place; writer and reader use these).
ATTR_TEMPLATE_REL = "leaffit:mls:template"
ATTR_CONTROLS = "leaffit:mls:templateControlPoints"
ATTR_K = "leaffit:mls:controlPointCount"
ATTR_TARGETS_PRIMVAR = "leaffit:mls:targetsPrimvar"
ATTR_VARIANT = "leaffit:mls:variant"
ATTR_KERNEL = "leaffit:mls:kernel"
ATTR_SIGMA = "leaffit:mls:sigma"
ATTR_REG = "leaffit:mls:regularizer"
ATTR_SHEET_OFFSET = "leaffit:mls:sheetOffset"
ATTR_VERSION = "leaffit:mls:version"
TARGETS_PRIMVAR = "primvars:leaffit:targets"
DEFORMER_VERSION = 1

log = logging.getLogger("leaffit_usd")


def is_known() -> bool:
    """True if USD's schema registry has the LeafFit deformer API (instantiates the registry)."""
    from pxr import Usd

    return Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(API_NAME) is not None


def fix_plug_info(path: Path) -> None:
    """Replace usdGenSchema's @PLUG_INFO_...@ placeholders for a codeless, resource-only plug-in."""
    text = path.read_text()
    header = "".join(l for l in text.splitlines(True) if l.startswith("#"))
    data = json.loads("".join(l for l in text.splitlines(True) if not l.startswith("#")))
    for plugin in data["Plugins"]:
        plugin.pop("LibraryPath", None)
        plugin["Root"] = "."
        plugin["ResourcePath"] = "."
    path.write_text(header + json.dumps(data, indent=4, sort_keys=True) + "\n")


def regenerate(schema_dir: Path = SCHEMA_DIR) -> None:
    """Run usdGenSchema on schema.usda (needs jinja2) and fix the generated plugInfo.json."""
    subprocess.run([sys.executable, "-m", "pxr.Usd.usdGenSchema", "-q", "schema.usda", "."],
                   cwd=schema_dir, check=True)
    fix_plug_info(schema_dir / "plugInfo.json")


if __name__ == "__main__":  # pragma: no cover - developer tool
    if "--regenerate" in sys.argv:
        regenerate()
        print(f"regenerated {SCHEMA_DIR}")
