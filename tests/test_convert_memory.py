"""``convert`` keeps one full copy of the Gaussians from the fit on (issue 13: the 1M convert
under 2 GB): the loaded cloud and the isolated input-frame cloud are released before the fit,
and what the report needs of them (counts, classes in file order) is kept. Run with ``--edits``,
the path that keeps the input-frame cloud longest (until the edits are replayed on it)."""
import gc
import importlib.util
import weakref

import numpy as np
import pytest

needs_samples = pytest.mark.skipif(importlib.util.find_spec("samples.generate") is None,
                                   reason="samples package missing")


@pytest.fixture
def plant(tmp_path_factory):
    from samples.generate import PlantSpec, make_plant, save_plant

    cloud, gt = make_plant(PlantSpec(kind="elliptic", leaves=3, gaussians=4000, holes=0.0,
                                     floaters=0.02, height=0.5), seed=7)
    ply, _ = save_plant(cloud, gt, tmp_path_factory.mktemp("in"), "plant")
    return ply, gt


def _options(**kw):
    from leaffit_usd.fit.params import FitParams
    from leaffit_usd.mesh.params import MeshParams
    from leaffit_usd.pipeline import ConvertOptions
    from leaffit_usd.segment.auto import SegmentParams
    from leaffit_usd.usd.writer import WriteOptions

    return ConvertOptions(fit=FitParams(K=12, steps=8, refine=2),
                          segment=SegmentParams(n_samples=1024, n_neighbors=128),
                          mesh=MeshParams(vertex_budget=256, texture_size=128),
                          write=WriteOptions(texture_max_size=128), tint=False, **kw)


def _spy(monkeypatch):
    """Weak references to the loaded and the isolated cloud, and whether each was still alive
    when the fit started."""
    import leaffit_usd.fit.register as reg
    import leaffit_usd.prepare as prepare
    import leaffit_usd.splats as splats

    refs, alive_at_fit = {}, {}
    real_load, real_isolate, real_fit = splats.load_cloud, prepare.isolate_stage, reg.fit_leaves

    def load(*a, **k):
        c = real_load(*a, **k)
        refs["loaded"] = weakref.ref(c)
        return c

    def isolate(*a, **k):
        c, iso = real_isolate(*a, **k)
        refs["isolated"] = weakref.ref(c)
        return c, iso

    def fit(*a, **k):
        gc.collect()
        alive_at_fit.update({name: r() is not None for name, r in refs.items()})
        return real_fit(*a, **k)

    monkeypatch.setattr(splats, "load_cloud", load)
    monkeypatch.setattr(prepare, "isolate_stage", isolate)   # the front half convert shares
    monkeypatch.setattr(reg, "fit_leaves", fit)
    return alive_at_fit


@needs_samples
def test_convert_releases_the_loaded_and_isolated_clouds_before_the_fit(plant, tmp_path, monkeypatch):
    """One conversion (with --edits, the path that keeps the input-frame cloud longest)."""
    from leaffit_usd.io_util import file_sha256
    from leaffit_usd.isolate import PLANT, decode_classes
    from leaffit_usd.pipeline import convert
    from leaffit_usd.segment.edits import Edits, save_edits

    ply, gt = plant
    tip = int(np.flatnonzero(np.asarray(gt.labels) == 1)[0])
    save_edits(Edits(input_sha256=file_sha256(ply), n_gaussians=len(gt.labels), height=0.5,
                     n_samples=1024, operations=[
                         {"op": "brush", "centers": [tip], "radius": 0.05, "mode": "replace"},
                         {"op": "assign", "label": 0}]), tmp_path / "e.json")
    alive = _spy(monkeypatch)
    rep = convert(ply, tmp_path / "plant.usda", _options(edits=str(tmp_path / "e.json")))
    assert rep["params"]["edits"] == str(tmp_path / "e.json")   # the edits were replayed
    assert rep["counts"]["leaves"] >= 1
    assert rep["isolation"]["removed"]["floater"] > 0      # the isolated cloud is its own copy
    assert alive == {"loaded": False, "isolated": False}
    # what the report keeps of them
    c = rep["counts"]
    classes = decode_classes(rep["isolation"]["classes"])
    assert c["gaussians_loaded"] == c["gaussians_in_file"] == len(classes) == 4000
    assert int((classes == PLANT).sum()) == c["gaussians"] < 4000
