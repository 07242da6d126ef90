"""Regenerate tests/splats/fixtures/formats/: small captures in every input format, each written
by an independent writer from the same INRIA PLY.

  sh3.ply / sh0.ply       our writer (300 Gaussians SH degree 3, 64 Gaussians SH degree 0)
  *.compressed.ply, *.sog, *.v3.spz, *.v4.spz
                          PlayCanvas splat-transform 3.7.0 (npm), the reference writer of the
                          compressed PLY and SOG formats (SPZ through Niantic's own encoder rules)
  *.splat                 gaussforge 0.6.0 (PyPI, C++), an antimatter15 .splat writer

Needs node/npx (npm registry) and ``pip install gaussforge==0.6.0``; neither is needed by the
tests, which read the committed files. Run from the repository root:
    .venv/bin/python scripts/make_format_fixtures.py
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from leaffit_usd.splats.cloud import GaussianCloud  # noqa: E402
from leaffit_usd.splats.ply import write_ply  # noqa: E402

OUT = ROOT / "tests" / "splats" / "fixtures" / "formats"
SPLAT_TRANSFORM = ["npx", "-y", "@playcanvas/splat-transform@3.7.0"]


def fixture_cloud(n: int, degree: int, seed: int, prototypes: int = 16) -> GaussianCloud:
    """Random Gaussians in a ~0.8-unit box off the origin, capture-like value ranges.

    Higher SH bands are drawn from ``prototypes`` shared vectors: SOG stores them as a palette
    (k-means), which represents a few distinct vectors exactly, so its test can hold the SH to the
    palette's 8-bit codebook instead of to k-means luck.
    """
    r = np.random.default_rng(seed)
    means = r.uniform(-0.4, 0.4, (n, 3)) + [0.2, -0.3, 0.7]
    q = r.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    m = (degree + 1) ** 2 - 1
    sh = np.zeros((n, m + 1, 3))
    sh[:, 0] = r.uniform(-1.5, 1.5, (n, 3))
    if m:
        sh[:, 1:] = r.uniform(-0.3, 0.3, (prototypes, m, 3))[r.integers(0, prototypes, n)]
    return GaussianCloud(means=means.astype(np.float32),
                         log_scales=r.uniform(-6, -2, (n, 3)).astype(np.float32),
                         quats=q.astype(np.float32),
                         opacity_logits=r.uniform(-3, 3, n).astype(np.float32),
                         sh=sh.astype(np.float32))


def main() -> None:
    import gaussforge

    OUT.mkdir(parents=True, exist_ok=True)
    gf = gaussforge.GaussForge()
    for name, cloud in (("sh3", fixture_cloud(300, 3, 1)), ("sh0", fixture_cloud(64, 0, 2))):
        ply = OUT / f"{name}.ply"
        write_ply(cloud, ply)
        for target, extra in ((f"{name}.compressed.ply", []), (f"{name}.sog", ["-g", "cpu"]),
                              (f"{name}.v3.spz", ["--spz-version", "3"]),
                              (f"{name}.v4.spz", ["--spz-version", "4"])):
            subprocess.run([*SPLAT_TRANSFORM, "-q", "-w", *extra, str(ply), str(OUT / target)],
                           check=True)
        res = gf.convert(ply.read_bytes(), "ply", "splat")
        if "error" in res:
            raise SystemExit(f"gaussforge: {res['error']}")
        (OUT / f"{name}.splat").write_bytes(res["data"])
    for p in sorted(OUT.iterdir()):
        print(f"{p.stat().st_size:8d}  {p.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
