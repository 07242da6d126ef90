"""The package's version (one place; the package root, the stage metadata and the CLI read it)."""
__version__ = "0.1.0"
