"""Malformed compressed PLY, SPZ, SOG and .splat files for the malformed-input suite (tests/test_cli.py)."""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

FIX = Path(__file__).parent / "fixtures" / "formats"


def malformed_format_files(d: Path) -> dict:
    """name -> (path, fragment of the one-line message)."""
    rng = np.random.default_rng(4)
    out = {}
    cp = (FIX / "sh3.compressed.ply").read_bytes()
    (d / "trunc.compressed.ply").write_bytes(cp[: len(cp) // 2])
    out["compressed_ply_truncated"] = (d / "trunc.compressed.ply", "compressed PLY")
    spz = (FIX / "sh3.v3.spz").read_bytes()
    (d / "trunc.spz").write_bytes(spz[: len(spz) // 2])
    out["spz_truncated"] = (d / "trunc.spz", "SPZ")
    v4 = (FIX / "sh3.v4.spz").read_bytes()
    (d / "trunc4.spz").write_bytes(v4[:40])
    out["spz_v4_truncated"] = (d / "trunc4.spz", "SPZ")
    (d / "garbage.spz").write_bytes(rng.integers(0, 256, 500, dtype=np.uint8).tobytes())
    out["spz_garbage"] = (d / "garbage.spz", "SPZ")
    (d / "trunc.sog").write_bytes((FIX / "sh3.sog").read_bytes()[:3000])
    out["sog_truncated"] = (d / "trunc.sog", "SOG")
    with zipfile.ZipFile(FIX / "sh3.sog") as z, zipfile.ZipFile(d / "nomeans.sog", "w") as w:
        for n in z.namelist():
            if n != "means_l.webp":
                w.writestr(n, z.read(n))
    out["sog_missing_image"] = (d / "nomeans.sog", "means_l.webp")
    with zipfile.ZipFile(d / "badmeta.sog", "w") as w:
        w.writestr("meta.json", "{not json")
    out["sog_bad_meta"] = (d / "badmeta.sog", "SOG")
    (d / "odd.splat").write_bytes((FIX / "sh0.splat").read_bytes()[:-5])
    out["splat_truncated"] = (d / "odd.splat", "32-byte records")
    bad = np.frombuffer((FIX / "sh0.splat").read_bytes(), np.uint8).copy().reshape(-1, 32)
    bad[:, 12:24] = np.frombuffer(np.full(3, -1.0, "<f4").tobytes(), np.uint8)  # negative scales
    (d / "negscale.splat").write_bytes(bad.tobytes())
    out["splat_not_splat"] = (d / "negscale.splat", "not a .splat file")
    (d / "empty.splat").write_bytes(b"")
    out["splat_empty"] = (d / "empty.splat", "empty")
    return out
