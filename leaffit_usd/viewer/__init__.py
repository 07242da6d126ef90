"""Interactive manual segmentation viewer (``leaffit-usd edit``): a local web server + a bundled page.

The page (``static/``) uses three.js (MIT, bundled — see ``static/BUILD.md``) and works offline.
"""
from leaffit_usd.viewer.server import ViewerServer, ViewerSession, build_session, create_app

__all__ = ["ViewerServer", "ViewerSession", "build_session", "create_app"]
