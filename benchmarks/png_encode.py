"""PNG encoder settings on real textures: time and size of ``image_io.write_image``'s setting
(zlib level ``PNG_LEVEL``, row filter ``PNG_FILTER``) against others, on every PNG under the
given folders (e.g. ``benchmarks/render.py --work DIR``'s converted plants).

Per setting: the mean encode time per image (best of ``--repeats``), the mean size, and the
smallest / largest size ratio against the first setting (level 9 with libpng's adaptive filters,
what image_io wrote before 65ac14e). Every encode is decoded and checked equal to its source.

    .venv/bin/python benchmarks/png_encode.py DIR [DIR ...] [--repeats 3]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

# (zlib level, libpng filter mask or None = libpng's adaptive choice): 8 none, 16 sub, 32 up,
# 64 average, 128 Paeth, 248 all
SETTINGS = [(9, None), (6, None), (6, 32), (7, 32), (8, 32), (9, 32)]


def encode(img: np.ndarray, path: Path, level: int, filt: int | None) -> float:
    """Write (H, W, 3|4) uint8 ``img`` as PNG at ``path``; returns the seconds the write took."""
    import OpenImageIO as oiio

    h, w, c = img.shape
    spec = oiio.ImageSpec(w, h, c, oiio.UINT8)
    if c == 4:
        spec.alpha_channel = 3
    buf = oiio.ImageBuf(spec)
    buf.set_pixels(oiio.ROI(0, w, 0, h, 0, 1, 0, c), np.ascontiguousarray(img))
    m = buf.specmod()
    m.attribute("oiio:UnassociatedAlpha", 1)
    m.attribute("oiio:ColorSpace", "sRGB")
    m.attribute("png:compressionLevel", level)
    if filt is not None:
        m.attribute("png:filter", filt)
    t = time.perf_counter()
    if not buf.write(str(path)):
        raise OSError(buf.geterror())
    return time.perf_counter() - t


def main(argv=None) -> int:
    from leaffit_usd.image_io import PNG_FILTER, PNG_LEVEL, read_image_u8

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args(argv)
    files = sorted(p for f in a.folders for p in Path(f).rglob("*.png"))
    if not files:
        print("no PNG files under", ", ".join(a.folders))
        return 2
    images = [read_image_u8(p) for p in files]
    print(f"{len(images)} images, shapes {sorted({im.shape for im in images})}; image_io writes "
          f"level {PNG_LEVEL} filter {PNG_FILTER}")
    base = None
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "t.png"
        for level, filt in SETTINGS:
            secs, sizes = [], []
            for im in images:
                secs.append(min(encode(im, out, level, filt) for _ in range(a.repeats)))
                sizes.append(out.stat().st_size)
                assert (read_image_u8(out)[..., :im.shape[2]] == im).all(), "PNG is lossless"
            sizes = np.asarray(sizes, float)
            base = sizes if base is None else base
            r = sizes / base
            print(f"level {level} filter {'adaptive' if filt is None else filt:>8}: "
                  f"{np.mean(secs):6.2f} s per image, {sizes.mean() / 1024:7.0f} KB mean, "
                  f"size / level-9-adaptive {r.min():.3f} .. {r.max():.3f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
