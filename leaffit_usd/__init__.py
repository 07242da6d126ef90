"""leaffit-usd: 3D Gaussian Splatting plant -> compact, editable USD asset (LeafFit, EG 2026).

Importing the package registers the LeafFit USD schema plug-in (see ``leaffit_usd.usd.schema``)
before anything else touches USD's schema registry.
"""
__version__ = "0.1.0"
