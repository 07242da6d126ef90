"""Reader and writer for ``UsdVol.ParticleField3DGaussianSplat`` (usd-core >= 26.x).

Mapping between :class:`GaussianCloud` (INRIA parameterisation) and the schema (activated values):

=============================  =====================================================================
GaussianCloud                  ParticleField3DGaussianSplat
=============================  =====================================================================
means (N, 3)                   ``positions`` point3f[] (local space of the prim)
quats (w, x, y, z)             ``orientations`` quatf[]; Gf.Quatf is (real, imaginary) = (w, x, y, z),
                               but the numpy view of a VtQuatfArray is (x, y, z, w) (imaginary
                               first), so the order is converted here and only here.
                               Written normalised (the schema expects unit quaternions).
exp(log_scales)                ``scales`` float3[] -- linear standard deviations (the kernel is a unit
                               Gaussian, so the scale is the standard deviation)
sigmoid(opacity_logits)        ``opacities`` float[] in [0, 1]
sh (N, C, 3)                   ``radiance:sphericalHarmonicsCoefficients`` float3[] of length N*C,
                               grouped by particle, C = (degree + 1)**2 contiguous coefficients each,
                               in the same basis order and INRIA scaling as the PLY
                               (colour = 0.28209 * dc + 0.5); ``radiance:sphericalHarmonicsDegree``
extra[name] (N,)               ``primvars:<name>`` with ``vertex`` interpolation; the numpy dtype is
                               kept in the attribute's customData ``leaffit:dtype``
=============================  =====================================================================

Because scales and opacities are stored activated, a PLY -> USD -> GaussianCloud round trip
equals the original in the activated values (scales, opacities, rotations) to float32
precision, not bit-for-bit in the log/logit parameters. Opacities of exactly 0 or 1 are clamped
to [1e-7, 1 - 1e-7] on reading so that their logits are finite.

Half-precision variants (``positionsh`` ...) are read when the float version is absent. On
reading, the prim's local-to-world transform is applied (a non-identity transform moves the
Gaussians into the stage's world frame, which is the frame a user clicks in); a
non-similarity transform is applied to the covariances exactly (eigen-decomposition).
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from leaffit_usd.errors import InputFileError
from leaffit_usd.geometry.quaternion import from_xyzw, to_xyzw
from leaffit_usd.io_util import atomic_path
from leaffit_usd.splats.cloud import REST_COUNTS, GaussianCloud, drop_invalid

log = logging.getLogger("leaffit_usd")

SCHEMA = "ParticleField3DGaussianSplat"
_OPACITY_EPS = 1e-7
_USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


def _pxr():
    from pxr import Sdf, Usd, UsdGeom, UsdVol, Vt  # noqa: F401  (imported lazily: slow)

    return Sdf, Usd, UsdGeom, UsdVol, Vt


# ---------------------------------------------------------------------------------------------
# reading
# ---------------------------------------------------------------------------------------------
def find_splat_prims(stage) -> list:
    """All ``ParticleField3DGaussianSplat`` prims of ``stage`` (active, loaded), in traversal order."""
    return [p for p in stage.Traverse() if p.GetTypeName() == SCHEMA]


def open_stage(path: str | os.PathLike):
    """Open a USD stage, turning every failure into an ``InputFileError``."""
    _, Usd, _, _, _ = _pxr()
    from pxr import Tf

    path = Path(path)
    if path.is_dir():
        raise InputFileError(path, "is a directory, not a USD file")
    if not path.is_file():
        raise InputFileError(path, "no such file")
    try:
        stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
    except Tf.ErrorException as e:
        raise InputFileError(path, f"not a readable USD file ({_usd_error_detail(e)})") from None
    if stage is None:
        raise InputFileError(path, "not a readable USD file")
    return stage


def _usd_error_detail(e) -> str:
    """A short, one-line reason from a Tf.ErrorException (no C++ namespaces)."""
    import re

    text = str(e)
    m = re.search(r":(\d+):(\d+): parse error", text)
    if m:
        return f"parse error at line {m.group(1)}, column {m.group(2)}"
    msgs = re.findall(r" : '(.*)'\s*$", text, flags=re.M)
    first = msgs[0] if msgs else (text.strip().splitlines() or [""])[0]
    first = re.sub(r"pxrInternal_\w+?::", "", first).strip()
    return (first[:120] + "...") if len(first) > 120 else (first or "parse error")


def read_usd_splats(path: str | os.PathLike, prim: str | None = None, drop_bad: bool = True,
                    apply_transform: bool = True) -> GaussianCloud:
    """Read one ``ParticleField3DGaussianSplat`` prim into a GaussianCloud (stage world frame).

    path : a .usd/.usda/.usdc/.usdz file. prim : the prim path (``/World/Plant``); needed only
    when the stage holds several splat prims. Values are read at the default time (or the first
    time sample when only samples are authored).

    Raises ``InputFileError`` for: unreadable files, no splat prim, several prims without
    ``prim``, a ``prim`` that does not exist or is not a splat, missing positions, arrays whose
    lengths disagree with the positions, an SH coefficient array that does not match the degree,
    and (with ``drop_bad``) clouds that are empty or mostly NaN/zero quaternions.
    """
    Sdf, Usd, UsdGeom, UsdVol, Vt = _pxr()
    path = Path(path)
    stage = open_stage(path)  # keep a reference: its prims expire with it
    p = _splat_prim(stage, path, prim)
    where = f"{path}:{p.GetPath()}"

    def get(name, hname, width):
        return _get_array(p, name, hname, width)

    means = get("positions", "positionsh", 3)
    if means is None:
        raise InputFileError(where, "splat prim has no 'positions'")
    n = len(means)
    if n == 0:
        raise InputFileError(where, "contains no Gaussians")

    def check(a, what):
        if a is not None and len(a) != n:
            raise InputFileError(where, f"'{what}' has {len(a)} values for {n} positions")
        return a

    xyzw = check(get("orientations", "orientationsh", 4), "orientations")
    scales = check(get("scales", "scalesh", 3), "scales")
    opac = check(get("opacities", "opacitiesh", 0), "opacities")
    if xyzw is None:
        quats = np.zeros((n, 4), np.float32)
        quats[:, 0] = 1.0
    else:
        quats = from_xyzw(xyzw)  # VtQuatfArray numpy = (x, y, z, w)
    if scales is None:
        raise InputFileError(where, "splat prim has no 'scales'")
    if opac is None:
        opac = np.ones(n, np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_scales = np.log(scales.astype(np.float64)).astype(np.float32)
        o = np.clip(opac.astype(np.float64), _OPACITY_EPS, 1 - _OPACITY_EPS)
        o[~np.isfinite(opac)] = np.nan
        logits = np.log(o / (1 - o)).astype(np.float32)

    sh = _read_sh(UsdVol.ParticleField3DGaussianSplat(p), get, n, where)
    cloud = GaussianCloud(means=np.ascontiguousarray(means), log_scales=log_scales, quats=quats,
                          opacity_logits=logits, sh=sh, extra=_read_extra(p, n))
    if apply_transform:
        m = np.asarray(UsdGeom.Xformable(p).ComputeLocalToWorldTransform(Usd.TimeCode.Default()),
                       np.float64).T  # Gf matrices are row-vector convention
        if not np.allclose(m, np.eye(4), atol=0, rtol=0):
            from leaffit_usd.splats.transform import transform_cloud

            cloud = transform_cloud(cloud, m, allow_affine=True)
    return drop_invalid(cloud, where) if drop_bad else cloud


def _splat_prim(stage, path: Path, prim: str | None):
    """The splat prim to read: ``prim`` (checked), or the stage's only one. InputFileError."""
    Sdf = _pxr()[0]
    if prim is not None:
        if not Sdf.Path.IsValidPathString(prim) or not Sdf.Path(prim).IsAbsolutePath():
            raise InputFileError(path, f"--prim {prim!r} is not an absolute prim path like /World/Plant")
        p = stage.GetPrimAtPath(prim)
        if not p or not p.IsValid():
            found = ", ".join(str(q.GetPath()) for q in find_splat_prims(stage)[:5]) or "none"
            raise InputFileError(path, f"no prim at {prim} (splat prims: {found})")
        if p.GetTypeName() != SCHEMA:
            raise InputFileError(path, f"prim {prim} is a {p.GetTypeName() or 'typeless prim'}, "
                                       f"not a {SCHEMA}")
        return p
    prims = find_splat_prims(stage)
    if not prims:
        raise InputFileError(path, f"no {SCHEMA} prim in this stage")
    if len(prims) > 1:
        names = ", ".join(str(q.GetPath()) for q in prims[:5]) + (" ..." if len(prims) > 5 else "")
        raise InputFileError(path, f"{len(prims)} {SCHEMA} prims ({names}); choose one with --prim")
    return prims[0]


def _get_array(p, name: str, hname: str, width: int):
    """Attribute ``name`` (or its half-precision twin ``hname``) as float32 (M, width), or None."""
    for n in (name, hname):
        attr = p.GetAttribute(n)
        if attr and attr.HasAuthoredValue() or (attr and attr.GetNumTimeSamples()):
            value = attr.Get(_read_time(attr))
            if value is None:
                continue
            a = np.asarray(value, dtype=np.float32)
            if width:
                a = a.reshape(-1, width)
            return a
    return None


def _read_sh(splat, get, n: int, where: str) -> np.ndarray:
    """(n, (degree + 1)^2, 3) float32 SH coefficients (DC only when none are authored)."""
    deg_attr = splat.GetRadianceSphericalHarmonicsDegreeAttr()
    coeffs = get("radiance:sphericalHarmonicsCoefficients", "radiance:sphericalHarmonicsCoefficientsh", 3)
    if coeffs is None:
        return np.zeros((n, 1, 3), np.float32)  # schema: missing -> DC (0.5, 0.5, 0.5) = coefficient 0
    degree = deg_attr.Get() if deg_attr else 3
    if degree is None:
        degree = 3
    degree = int(degree)
    if degree not in REST_COUNTS:
        raise InputFileError(where, f"radiance:sphericalHarmonicsDegree is {degree}; supported 0-3")
    c = (degree + 1) ** 2
    if len(coeffs) < n * c:
        raise InputFileError(where, f"{len(coeffs)} SH coefficients for {n} particles of SH degree "
                                    f"{degree} (need {n * c})")
    if len(coeffs) > n * c:
        log.warning("%s: %d extra SH coefficients ignored", where, len(coeffs) - n * c)
    return np.ascontiguousarray(coeffs[: n * c].reshape(n, c, 3))


def _read_extra(p, n: int) -> dict:
    """Per-Gaussian primvars (1-D, n values) in their written order and dtype."""
    UsdGeom = _pxr()[2]
    extra = {}
    for pv in UsdGeom.PrimvarsAPI(p).GetPrimvarsWithAuthoredValues():
        name = pv.GetPrimvarName()
        if name in ("displayColor", "displayOpacity") or ":" in name:
            continue
        val = pv.Get(_read_time(pv.GetAttr()))
        if val is None:
            continue
        a = np.asarray(val)
        if a.ndim != 1 or len(a) != n:
            continue  # constant or multi-component primvars are not per-Gaussian properties
        dt = pv.GetAttr().GetCustomDataByKey("leaffit:dtype")
        extra[name] = a.astype(np.dtype(dt) if dt else a.dtype)
    order = p.GetCustomDataByKey("leaffit:extraOrder")  # primvars come back sorted by name
    if order:
        rank = {k: i for i, k in enumerate(order)}
        extra = dict(sorted(extra.items(), key=lambda kv: rank.get(kv[0], len(rank))))
    return extra


def _read_time(attr):
    from pxr import Usd

    if attr.HasAuthoredValue():
        return Usd.TimeCode.Default()
    samples = attr.GetTimeSamples()
    return Usd.TimeCode(samples[0]) if samples else Usd.TimeCode.Default()


# ---------------------------------------------------------------------------------------------
# writing
# ---------------------------------------------------------------------------------------------
_VT_ARRAY = {"f4": "FloatArray", "f8": "DoubleArray", "i4": "IntArray", "u4": "UIntArray",
             "i8": "Int64Array", "u8": "UInt64Array", "u1": "UCharArray",
             "i1": "IntArray", "i2": "IntArray", "u2": "IntArray"}
_SDF_TYPE = {"f4": "FloatArray", "f8": "DoubleArray", "i4": "IntArray", "u4": "UIntArray",
             "i8": "Int64Array", "u8": "UInt64Array", "u1": "UCharArray",
             "i1": "IntArray", "i2": "IntArray", "u2": "IntArray"}


def write_usd_splats(cloud: GaussianCloud, path: str | os.PathLike, prim: str = "/Splats",
                     up_axis: str = "Z", meters_per_unit: float | None = None) -> None:
    """Write ``cloud`` as one ``ParticleField3DGaussianSplat`` prim (the stage's default prim).

    path : .usda (text), .usdc/.usd (crate) or .usdz. The Gaussians are written in the cloud's
    own frame (positions = means); ``up_axis`` and ``meters_per_unit`` are stage metadata only.
    Written atomically.
    """
    Sdf, Usd, UsdGeom, UsdVol, Vt = _pxr()
    path = Path(path)
    if path.suffix.lower() not in _USD_SUFFIXES:
        raise InputFileError(path, f"not a USD file name (use one of {', '.join(_USD_SUFFIXES)})")
    if path.suffix.lower() == ".usdz":
        import tempfile

        with tempfile.TemporaryDirectory(prefix="leaffit-usdz-") as d:
            inner = Path(d) / (path.stem + ".usdc")
            _author_splats(cloud, inner, prim, up_axis, meters_per_unit)
            from pxr import UsdUtils

            with atomic_path(path) as tmp:
                if not UsdUtils.CreateNewUsdzPackage(str(inner), str(tmp)):
                    raise OSError(f"could not write {path}")
        return
    with atomic_path(path) as tmp:
        _author_splats(cloud, tmp, prim, up_axis, meters_per_unit)


def _author_splats(cloud, stage_path, prim, up_axis, meters_per_unit) -> None:
    Sdf, Usd, UsdGeom, UsdVol, Vt = _pxr()
    n = len(cloud)
    stage = Usd.Stage.CreateNew(str(stage_path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z if up_axis.upper() == "Z" else UsdGeom.Tokens.y)
    if meters_per_unit:
        UsdGeom.SetStageMetersPerUnit(stage, float(meters_per_unit))
    splat = UsdVol.ParticleField3DGaussianSplat.Define(stage, Sdf.Path(prim))
    stage.SetDefaultPrim(stage.GetPrimAtPath(Sdf.Path(prim).GetPrefixes()[0]))
    means = np.ascontiguousarray(cloud.means, np.float32)
    splat.CreatePositionsAttr().Set(Vt.Vec3fArray.FromNumpy(means))
    xyzw = to_xyzw(np.asarray(cloud.rotations, np.float32))  # ours w,x,y,z -> Vt x,y,z,w
    splat.CreateOrientationsAttr().Set(Vt.QuatfArray.FromNumpy(xyzw))
    splat.CreateScalesAttr().Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(cloud.scales, np.float32)))
    splat.CreateOpacitiesAttr().Set(Vt.FloatArray.FromNumpy(np.ascontiguousarray(cloud.opacities)))
    splat.CreateRadianceSphericalHarmonicsDegreeAttr().Set(int(cloud.sh_degree))
    splat.CreateRadianceSphericalHarmonicsCoefficientsAttr().Set(
        Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(cloud.sh.reshape(-1, 3), np.float32)))
    if n:
        lo = means.min(0).astype(np.float64)
        hi = means.max(0).astype(np.float64)
        pad = 3.0 * float(cloud.scales.max())  # 3-sigma support of the widest kernel
        splat.CreateExtentAttr().Set(Vt.Vec3fArray.FromNumpy(
            np.stack([lo - pad, hi + pad]).astype(np.float32)))
    pvapi = UsdGeom.PrimvarsAPI(splat.GetPrim())
    written = []
    for name, values in cloud.extra.items():
        v = np.asarray(values)
        if v.ndim != 1 or not Sdf.Path.IsValidNamespacedIdentifier(name):
            log.warning("extra property %r not written to USD (not a per-Gaussian scalar "
                        "with a valid name)", name)
            continue
        key = v.dtype.str[1:]
        if key not in _VT_ARRAY:
            log.warning("extra property %r of dtype %s not written to USD", name, v.dtype)
            continue
        pv = pvapi.CreatePrimvar(name, getattr(Sdf.ValueTypeNames, _SDF_TYPE[key]),
                                 UsdGeom.Tokens.vertex)
        conv = np.dtype({"i1": "i4", "i2": "i4", "u2": "i4"}.get(key, key))  # native byte order
        pv.Set(getattr(Vt, _VT_ARRAY[key]).FromNumpy(np.ascontiguousarray(v, dtype=conv)))
        pv.GetAttr().SetCustomDataByKey("leaffit:dtype", np.dtype(key).str)
        written.append(name)
    if written:
        splat.GetPrim().SetCustomDataByKey("leaffit:extraOrder", Vt.StringArray(written))
    stage.GetRootLayer().Save()
