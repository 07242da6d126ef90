"""leaffit-usd: 3D Gaussian Splatting plant -> compact, editable USD asset (LeafFit, EG 2026).

Importing the package registers the LeafFit USD schema plug-in (:mod:`leaffit_usd.schema_plugin`)
before anything else touches USD's schema registry, without importing ``pxr`` when it is not
loaded yet (commands that never touch USD, such as ``segment``, do not import it).
"""
from leaffit_usd.schema_plugin import register_on_import
from leaffit_usd.version import __version__

register_on_import()


def open_plant(path, *args, **kwargs):
    """Open a LeafFit USD stage for scripting (see :func:`leaffit_usd.api.open_plant`)."""
    from leaffit_usd.api import open_plant as _open

    return _open(path, *args, **kwargs)


__all__ = ["__version__", "open_plant"]
