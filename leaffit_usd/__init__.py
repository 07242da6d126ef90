"""leaffit-usd: 3D Gaussian Splatting plant -> compact, editable USD asset (LeafFit, EG 2026).

Importing the package registers the LeafFit USD schema plug-in (see ``leaffit_usd.usd.schema``)
before anything else touches USD's schema registry.
"""
__version__ = "0.1.0"


def _register_schema() -> None:
    # Must run before the first use of Usd.SchemaRegistry in this process (later registration is
    # ignored silently by USD). Importing pxr.Plug alone does not instantiate that registry.
    try:
        from leaffit_usd.usd.schema import register
    except ImportError:  # pragma: no cover - usd-core missing: only the USD parts will fail
        return
    register()


_register_schema()


def open_plant(path, *args, **kwargs):
    """Open a LeafFit USD stage for scripting (see :func:`leaffit_usd.api.open_plant`)."""
    from leaffit_usd.api import open_plant as _open

    return _open(path, *args, **kwargs)
