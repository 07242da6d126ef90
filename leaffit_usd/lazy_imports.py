"""Defer two NumPy submodules that every command's start-up loads and none uses.

SciPy (1.14 to at least 1.17) reaches NumPy through its array-API shim, which runs
``from numpy import *``. NumPy 2 lists its lazily loaded submodules in ``__all__``, so that one
line, run by any ``import scipy.sparse`` or ``scipy.spatial``, imports ``numpy.f2py`` (the Fortran
wrapper generator, with ``charset_normalizer``) and ``numpy.testing`` (with ``unittest``,
``email``, ``importlib.metadata``): about 0.15 s of CPU per process on this project's 2-core
machine, beside a ``segment`` run of a few seconds (``benchmarks/segment_time.py`` prints the
whole-process time).

:func:`defer` registers both as lazy modules (the standard library's
``importlib.util.LazyLoader``, the recipe of the ``importlib`` documentation): the module object
exists, ``import numpy.testing`` succeeds, and its code runs on the first attribute access, so
whoever uses them later gets the real module, loaded then. The star import only binds the
names, so they stay unloaded.

Why only these two: ``numpy.ma`` is used by ``np.unique`` itself, and a subpackage that its
package's ``__init__`` imports by name (``scipy.spatial.transform``) is loaded at once by the
import system's ``__spec__`` check (Python 3.11), so deferring them saves nothing.

Only the command-line entry point calls :func:`defer` (not ``import leaffit_usd``: a library
user's process is left as it is). A module that is loaded already, or that this NumPy does not
have, is skipped; nothing here changes what any function computes.
"""
from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
import sys

#: Submodules of a top-level package that ``from numpy import *`` loads and the commands never use.
DEFERRED = ("numpy.f2py", "numpy.testing")


def _defer_one(full: str) -> bool:
    """Register ``full`` (``package.submodule``) as a lazy module; True if it was deferred."""
    if full in sys.modules:
        return False
    parent, _, name = full.rpartition(".")
    package = importlib.import_module(parent)  # numpy: every command imports it anyway
    spec = importlib.machinery.PathFinder.find_spec(full, package.__path__)
    if spec is None or spec.loader is None:
        return False
    spec.loader = importlib.util.LazyLoader(spec.loader)
    module = importlib.util.module_from_spec(spec)
    sys.modules[full] = module
    spec.loader.exec_module(module)
    # as the import system does for a loaded submodule; else NumPy's module ``__getattr__``
    # would import it again, for real, on ``numpy.testing``
    setattr(package, name, module)
    return True


def defer(modules=DEFERRED) -> list[str]:
    """Register each of ``modules`` (dotted names) as a lazy module; returns those deferred (the
    others were loaded already or are not there)."""
    done = []
    for full in modules:
        try:
            if _defer_one(full):
                done.append(full)
        except (ImportError, ValueError, AttributeError):  # a layout we do not know: leave it
            continue
    return done
