"""USD ParticleField3DGaussianSplat reader/writer: round trips and validation."""
import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdVol, Vt

from leaffit_usd.errors import InputFileError
from leaffit_usd.splats import load_cloud, read_ply, write_ply
from leaffit_usd.splats.usd_io import read_usd_splats, write_usd_splats
from tests.splats.plyfiles import small_cloud

F32 = dict(rtol=3e-7, atol=0)  # float32 precision (one or two ulps after exp/log, sigmoid/logit)


def assert_float32_equal(a, b):
    np.testing.assert_array_equal(b.means, a.means)
    np.testing.assert_array_equal(b.sh, a.sh)
    np.testing.assert_allclose(b.scales, a.scales, **F32)
    np.testing.assert_allclose(b.opacities, a.opacities, rtol=3e-7, atol=1e-7)
    # rotations: same unit quaternion (our w,x,y,z) up to float32 rounding
    np.testing.assert_allclose(b.rotations, a.rotations, rtol=0, atol=2e-7)
    np.testing.assert_allclose(b.covariances(), a.covariances(), rtol=2e-5, atol=1e-12)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
@pytest.mark.parametrize("suffix", [".usda", ".usdc", ".usdz"])
def test_ply_usd_round_trip(tmp_path, degree, suffix):
    cloud = small_cloud(120, degree, seed=degree, extra=True)
    cloud.opacity_logits[:3] = [-12.0, 0.0, 12.0]
    write_ply(cloud, tmp_path / "a.ply")
    ply = read_ply(tmp_path / "a.ply")
    write_usd_splats(ply, tmp_path / f"a{suffix}")
    usd = load_cloud(tmp_path / f"a{suffix}")
    assert usd.sh_degree == degree and len(usd) == len(ply)
    assert_float32_equal(ply, usd)
    assert list(usd.extra) == list(ply.extra)
    for k, v in ply.extra.items():
        assert usd.extra[k].dtype == v.dtype and np.array_equal(usd.extra[k], v), k
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["a.ply", f"a{suffix}"])  # no temp files


def test_quaternion_order_against_gf(tmp_path):
    """Our (w, x, y, z) becomes Gf.Quatf(real=w, imaginary=(x, y, z)) in the stage."""
    cloud = small_cloud(3)
    cloud.quats[:] = [[0.5, 0.5, -0.5, 0.5]] * 3
    write_usd_splats(cloud, tmp_path / "q.usda")
    stage = Usd.Stage.Open(str(tmp_path / "q.usda"))
    q = UsdVol.ParticleField3DGaussianSplat(stage.GetPrimAtPath("/Splats")).GetOrientationsAttr().Get()[0]
    assert q.GetReal() == pytest.approx(0.5)
    assert tuple(q.GetImaginary()) == pytest.approx((0.5, -0.5, 0.5))
    assert "upAxis" in (tmp_path / "q.usda").read_text()


def test_activated_values_in_stage(tmp_path):
    cloud = small_cloud(5, 1)
    write_usd_splats(cloud, tmp_path / "v.usdc")
    stage = Usd.Stage.Open(str(tmp_path / "v.usdc"))  # keep the stage alive while using its prims
    prim = stage.GetPrimAtPath("/Splats")
    s = UsdVol.ParticleField3DGaussianSplat(prim)
    np.testing.assert_allclose(np.asarray(s.GetScalesAttr().Get()), np.exp(cloud.log_scales), rtol=1e-6)
    op = np.asarray(s.GetOpacitiesAttr().Get())
    assert (op > 0).all() and (op < 1).all()
    assert s.GetRadianceSphericalHarmonicsDegreeAttr().Get() == 1
    assert len(s.GetRadianceSphericalHarmonicsCoefficientsAttr().Get()) == 5 * 4


def _stage(tmp_path, name="s.usda", n_prims=1, n=10, degree=0, xform=None):
    path = tmp_path / name
    stage = Usd.Stage.CreateNew(str(path))
    rng = np.random.default_rng(0)
    for k in range(n_prims):
        s = UsdVol.ParticleField3DGaussianSplat.Define(stage, f"/World/P{k}")
        s.CreatePositionsAttr().Set(Vt.Vec3fArray.FromNumpy(rng.normal(size=(n, 3)).astype(np.float32)))
        s.CreateScalesAttr().Set(Vt.Vec3fArray.FromNumpy(np.full((n, 3), 0.1, np.float32)))
        s.CreateOrientationsAttr().Set(Vt.QuatfArray([Gf.Quatf(1, 0, 0, 0)] * n))
        s.CreateOpacitiesAttr().Set(Vt.FloatArray([0.5] * n))
        s.CreateRadianceSphericalHarmonicsDegreeAttr().Set(degree)
        s.CreateRadianceSphericalHarmonicsCoefficientsAttr().Set(
            Vt.Vec3fArray.FromNumpy(np.zeros((n * (degree + 1) ** 2, 3), np.float32)))
        if xform is not None:
            s.AddTransformOp().Set(Gf.Matrix4d(*np.asarray(xform, float).T.ravel()))
    stage.GetRootLayer().Save()
    return path, stage


def test_prim_selection(tmp_path):
    path, _ = _stage(tmp_path, n_prims=2)
    with pytest.raises(InputFileError, match="2 ParticleField3DGaussianSplat prims.*--prim"):
        load_cloud(path)
    assert len(load_cloud(path, prim="/World/P1")) == 10
    with pytest.raises(InputFileError, match="no prim at /World/Nope"):
        load_cloud(path, prim="/World/Nope")
    with pytest.raises(InputFileError, match="not a ParticleField3DGaussianSplat"):
        load_cloud(path, prim="/World")
    with pytest.raises(InputFileError, match="absolute prim path"):
        load_cloud(path, prim="World/P1")


def test_no_splat_prim(tmp_path):
    path = tmp_path / "mesh.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Mesh.Define(stage, "/World/Mesh")
    stage.GetRootLayer().Save()
    with pytest.raises(InputFileError, match="no ParticleField3DGaussianSplat prim"):
        load_cloud(path)


def test_length_mismatch_and_sh_mismatch(tmp_path):
    path, stage = _stage(tmp_path, degree=2)
    s = UsdVol.ParticleField3DGaussianSplat(stage.GetPrimAtPath("/World/P0"))
    s.GetScalesAttr().Set(Vt.Vec3fArray([Gf.Vec3f(1, 1, 1)] * 4))
    stage.GetRootLayer().Save()
    with pytest.raises(InputFileError, match="'scales' has 4 values for 10 positions"):
        load_cloud(path)
    s.GetScalesAttr().Set(Vt.Vec3fArray([Gf.Vec3f(1, 1, 1)] * 10))
    s.GetRadianceSphericalHarmonicsCoefficientsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(0, 0, 0)] * 20))
    stage.GetRootLayer().Save()
    with pytest.raises(InputFileError, match="need 90"):
        load_cloud(path)


def test_missing_positions(tmp_path):
    path = tmp_path / "np.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdVol.ParticleField3DGaussianSplat.Define(stage, "/P")
    stage.GetRootLayer().Save()
    with pytest.raises(InputFileError, match="no 'positions'"):
        load_cloud(path)


def test_garbage_usda(tmp_path):
    path = tmp_path / "bad.usda"
    path.write_text("#usda 1.0\ndef Xform \"A\" {\n  float x = \n")
    with pytest.raises(InputFileError, match="not a readable USD file"):
        load_cloud(path)


def test_prim_transform_is_applied(tmp_path):
    m = np.eye(4)
    m[:3, :3] = 2.0 * np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
    m[:3, 3] = [1, 2, 3]
    p0, _ = _stage(tmp_path, "a.usda")
    p1, _ = _stage(tmp_path, "b.usda", xform=m)
    a, b = load_cloud(p0), load_cloud(p1)
    np.testing.assert_allclose(b.means, a.means @ m[:3, :3].T + m[:3, 3], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(b.scales, 2 * a.scales, rtol=1e-6)
    raw = read_usd_splats(p1, apply_transform=False)
    np.testing.assert_array_equal(raw.means, a.means)


def test_missing_optional_attributes_defaults(tmp_path):
    path = tmp_path / "min.usda"
    stage = Usd.Stage.CreateNew(str(path))
    s = UsdVol.ParticleField3DGaussianSplat.Define(stage, "/P")
    s.CreatePositionsAttr().Set(Vt.Vec3fArray([Gf.Vec3f(0, 0, i) for i in range(4)]))
    s.CreateScalesAttr().Set(Vt.Vec3fArray([Gf.Vec3f(1, 1, 1)] * 4))
    stage.GetRootLayer().Save()
    c = load_cloud(path)
    assert c.sh_degree == 0 and np.allclose(c.colors, 0.5)  # schema: missing SH -> DC 0.5 grey
    np.testing.assert_array_equal(c.quats, np.tile([1, 0, 0, 0], (4, 1)))


def test_prim_option_on_ply_is_an_error(tmp_path):
    write_ply(small_cloud(5), tmp_path / "a.ply")
    with pytest.raises(InputFileError, match="USD files only"):
        load_cloud(tmp_path / "a.ply", prim="/P")


def test_half_precision_attributes_are_read(tmp_path):
    path = tmp_path / "half.usda"
    stage = Usd.Stage.CreateNew(str(path))
    s = UsdVol.ParticleField3DGaussianSplat.Define(stage, "/P")
    pos = np.array([[0, 0, 0], [1, 2, 3], [0.5, 0.25, 4]], np.float16)
    s.CreatePositionshAttr().Set(Vt.Vec3hArray.FromNumpy(pos))
    s.CreateScaleshAttr().Set(Vt.Vec3hArray.FromNumpy(np.full((3, 3), 0.125, np.float16)))
    s.CreateOpacitieshAttr().Set(Vt.HalfArray.FromNumpy(np.array([0.5, 0.25, 0.75], np.float16)))
    stage.GetRootLayer().Save()
    c = load_cloud(path)
    np.testing.assert_array_equal(c.means, pos.astype(np.float32))
    np.testing.assert_allclose(c.scales, 0.125, rtol=1e-6)
    np.testing.assert_allclose(c.opacities, [0.5, 0.25, 0.75], rtol=1e-6)


def test_write_rejects_non_usd_name(tmp_path):
    with pytest.raises(InputFileError, match="not a USD file name"):
        write_usd_splats(small_cloud(3), tmp_path / "a.ply")
