"""``leaffit_usd.lazy_imports``: the command line defers ``numpy.f2py`` and ``numpy.testing``
(loaded by SciPy's ``from numpy import *``, used by no command) and they still work when used."""
import subprocess
import sys

import numpy as np

from leaffit_usd.cli import main
from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.splats.ply import write_ply


def _child(code: str) -> list[str]:
    """Run ``code`` in a fresh interpreter (this test process has NumPy's submodules loaded
    already); its printed words."""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return out.stdout.split()


LAZY = "type(sys.modules.get({!r})).__name__ == '_LazyModule'"


def test_scipy_import_leaves_deferred_modules_unloaded_and_they_still_work():
    code = ("import sys\n"
            "from leaffit_usd.lazy_imports import defer\n"
            "print(len(defer()))\n"
            "import scipy.sparse, scipy.sparse.csgraph, scipy.spatial\n"  # runs `from numpy import *`
            f"print({LAZY.format('numpy.f2py')}, {LAZY.format('numpy.testing')})\n"
            "import numpy as np, numpy.testing as t\n"
            "t.assert_allclose(np.ones(3), np.ones(3))\n"  # first use loads the real module
            f"print({LAZY.format('numpy.testing')}, np.testing is t, hasattr(t, 'assert_array_equal'))\n"
            "from numpy.testing import assert_equal\n"
            "print(callable(assert_equal))\n")
    assert _child(code) == ["2", "True", "True", "False", "True", "True", "True"]


def test_defer_skips_loaded_and_missing_modules():
    from leaffit_usd.lazy_imports import defer

    assert defer(("numpy.testing", "numpy.no_such_module", "numpy.linalg")) == []


def test_segment_run_keeps_them_unloaded(tmp_path):
    """A whole ``segment`` run in a fresh process never touches them (else deferring is moot)."""
    rng = np.random.default_rng(0)
    n = 3000
    t = rng.uniform(0, 1, n)
    means = np.c_[0.05 * rng.normal(size=(n, 2)) * (t[:, None] > 0.5), t]  # a stalk and a tuft
    cloud = GaussianCloud.from_activated(means, np.full((n, 3), 0.005), np.tile([1.0, 0, 0, 0], (n, 1)),
                                         np.full(n, 0.8), colors=np.full((n, 3), 0.4))
    ply = tmp_path / "p.ply"
    write_ply(cloud, ply)
    code = ("import sys\n"
            "from leaffit_usd.cli import main\n"
            f"rc = main(['segment', {str(ply)!r}, '-o', {str(tmp_path / 'l.npz')!r}, '--up', '+z', '-q'])\n"
            f"print(rc, {LAZY.format('numpy.f2py')}, {LAZY.format('numpy.testing')})\n")
    assert _child(code) == ["0", "True", "True"]
