"""leaffit-usd: 3D Gaussian Splatting plant -> compact, editable USD asset (LeafFit, EG 2026).

Importing the package registers the LeafFit USD schema plug-in (see ``leaffit_usd.usd.schema``)
before anything else touches USD's schema registry: through USD's API when ``pxr`` is loaded
already, else by naming it in ``PXR_PLUGINPATH_NAME``, which USD reads when its plug-in
registry starts (so commands that never touch USD, such as ``segment``, do not import it).
"""
__version__ = "0.1.0"


def _register_schema() -> None:
    # Must happen before the first use of Usd.SchemaRegistry in this process (later registration
    # is ignored silently by USD).
    import sys

    try:
        from leaffit_usd.usd.schema import announce, register
    except ImportError:  # pragma: no cover - usd-core missing: only the USD parts will fail
        return
    if "pxr" in sys.modules:  # USD is loaded already: register through its API, now
        register()
    else:  # not yet: USD's plug-in registry reads the path when it starts (no pxr import here)
        announce()


_register_schema()


def open_plant(path, *args, **kwargs):
    """Open a LeafFit USD stage for scripting (see :func:`leaffit_usd.api.open_plant`)."""
    from leaffit_usd.api import open_plant as _open

    return _open(path, *args, **kwargs)
