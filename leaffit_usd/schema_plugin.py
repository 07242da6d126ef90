"""The LeafFit codeless USD schema plug-in (``leaffit_usd/schemas/``): where it is and how USD is
told about it. On the ground floor so that the package root can register it on import without
importing a higher layer; the schema's attribute names and its regeneration live in
:mod:`leaffit_usd.usd.schema`.

A plug-in registered after ``Usd.SchemaRegistry`` was first used is ignored silently
(``ApplyAPI`` then raises), so ``import leaffit_usd`` registers it first: through USD's API when
``pxr`` is loaded already (:func:`register`), else by naming it in ``PXR_PLUGINPATH_NAME``
(:func:`announce`), which USD reads when its plug-in registry starts -- commands that never
touch USD (``segment``) then do not import it.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

SCHEMA_DIR = Path(__file__).resolve().parent / "schemas"
_registered = False


def register() -> bool:
    """Register the schema plug-in (idempotent). Returns True if USD knows the API afterwards."""
    global _registered
    if _registered:
        return True
    from pxr import Plug

    Plug.Registry().RegisterPlugins(str(SCHEMA_DIR))
    _registered = True
    return True


def announce() -> None:
    """Put ``SCHEMA_DIR`` first on ``PXR_PLUGINPATH_NAME`` (idempotent), USD's documented way to
    name plug-ins: its plug-in registry reads the variable when it first starts, so the schema
    is known without importing ``pxr`` now (about 0.1 s of start-up). Too late once USD's
    registry has started; :func:`register` covers that case."""
    paths = [p for p in os.environ.get("PXR_PLUGINPATH_NAME", "").split(os.pathsep) if p]
    if str(SCHEMA_DIR) not in paths:
        os.environ["PXR_PLUGINPATH_NAME"] = os.pathsep.join([str(SCHEMA_DIR), *paths])


def register_on_import() -> None:
    """What ``import leaffit_usd`` does: :func:`register` when ``pxr`` is loaded already, else
    :func:`announce` (no ``pxr`` import). Without usd-core only the USD parts will fail."""
    if "pxr" in sys.modules:
        try:
            register()
        except ImportError:  # pragma: no cover - a broken usd-core
            return
    else:
        announce()
