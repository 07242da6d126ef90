"""Byte-identical outputs (DESIGN: "a fixed seed gives byte-identical output").

Two conversions of the same capture, one with 2 torch threads and one with 1 (``batch`` runs its
jobs with fewer threads than ``convert`` uses), give the same bytes: the stage, the baked-leaves
payload and both textures. The torch numerics run with one intra-op thread whatever the caller
set (``leaffit_usd.determinism``): checked directly, since a small plant may not expose the
thread-dependent summation order that 200 Adam steps on a real plant turn into different fits.
"""
import hashlib
import importlib.util

import numpy as np
import pytest
import torch

from leaffit_usd.determinism import deterministic_torch

needs_samples = pytest.mark.skipif(importlib.util.find_spec("samples.generate") is None,
                                   reason="samples package missing")


def _digests(folder):
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@needs_samples
def test_two_conversions_identical_bytes_across_thread_counts(tmp_path):
    from samples.generate import PlantSpec, make_plant, save_plant

    from leaffit_usd.fit.params import FitParams
    from leaffit_usd.mesh.params import MeshParams
    from leaffit_usd.pipeline import ConvertOptions, convert
    from leaffit_usd.segment.auto import SegmentParams
    from leaffit_usd.usd.writer import WriteOptions

    cloud, gt = make_plant(PlantSpec(kind="elliptic", leaves=3, gaussians=4000, holes=0.0,
                                     floaters=0.0, height=0.5), seed=7)
    ply, _ = save_plant(cloud, gt, tmp_path / "in", "plant")
    opts = ConvertOptions(fit=FitParams(K=12, steps=8, refine=2),
                          segment=SegmentParams(n_samples=1024, n_neighbors=128),
                          mesh=MeshParams(vertex_budget=256, texture_size=128),
                          write=WriteOptions(texture_max_size=128))
    saved = torch.get_num_threads()
    reports, digests = [], []
    try:
        for i, threads in enumerate((2, 1)):
            torch.set_num_threads(threads)
            out = tmp_path / f"run{i}"
            reports.append(convert(ply, out / "plant.usda", opts))
            digests.append(_digests(out))
            assert torch.get_num_threads() == threads      # the caller's setting is restored
    finally:
        torch.set_num_threads(saved)
    assert set(digests[0]) == {"plant.usda", "plant.geom.usdc", "plant.baked.usdc", "plant.variants.usdc",
                               "textures/plant.front.jpg",
                               "textures/plant.back.jpg", "textures/plant.front.mask.png",
                               "textures/plant.back.mask.png"}
    assert digests[0] == digests[1]
    assert reports[0]["fit"]["per_leaf"] == reports[1]["fit"]["per_leaf"]
    # and nothing of the run itself (times, folders) is in the stage
    text = (tmp_path / "run0" / "plant.usda").read_text()
    assert str(tmp_path) not in text and "run0" not in text


@needs_samples
def test_the_asset_does_not_depend_on_the_file_order(tmp_path):
    """The same capture with its Gaussians in another file order (a format converter may sort
    the splats, e.g. by Morton code) converts to the same bytes: geometry, baked payload,
    textures, and a stage that differs only where it names the input file (its name, its
    SHA-256, the root Gaussian's index in it). ``convert`` works on the plant in an order of
    positions alone (``geometry.sampling.canonical_order``)."""
    import re

    from samples.generate import PlantSpec, make_plant, save_plant

    from leaffit_usd.fit.params import FitParams
    from leaffit_usd.mesh.params import MeshParams
    from leaffit_usd.pipeline import ConvertOptions, convert
    from leaffit_usd.segment.auto import SegmentParams
    from leaffit_usd.splats import load_cloud
    from leaffit_usd.splats.ply import write_ply
    from leaffit_usd.usd.writer import WriteOptions

    cloud, gt = make_plant(PlantSpec(kind="elliptic", leaves=3, gaussians=4000, holes=0.0,
                                     floaters=0.0, height=0.5), seed=7)
    ply, _ = save_plant(cloud, gt, tmp_path / "in", "plant")
    loaded = load_cloud(ply, drop_bad=False)
    perm = np.random.default_rng(3).permutation(loaded.file_count)
    shuffled = loaded.subset(perm)
    shuffled.file_index = np.arange(len(perm))     # a new file, in the shuffled order
    write_ply(shuffled, tmp_path / "in" / "shuffled.ply")
    opts = ConvertOptions(fit=FitParams(K=12, steps=8, refine=2),
                          segment=SegmentParams(n_samples=1024, n_neighbors=128),
                          mesh=MeshParams(vertex_budget=256, texture_size=128),
                          write=WriteOptions(texture_max_size=128))
    reports, digests, stages = [], [], []
    for i, src in enumerate((ply, tmp_path / "in" / "shuffled.ply")):
        out = tmp_path / f"run{i}"
        reports.append(convert(src, out / "plant.usda", opts))
        digests.append({k: v for k, v in _digests(out).items() if k != "plant.usda"})
        text = (out / "plant.usda").read_text()
        stages.append(re.sub(r'(inputSha256|input_sha256|input_name|root_gaussian)("?\s*[:=]\s*)("[^"]*"|\d+)',
                             r"\1\2X", text))
    assert digests[0] == digests[1] and len(digests[0]) == 7
    assert stages[0] == stages[1]
    assert reports[0]["fit"]["per_leaf"] == reports[1]["fit"]["per_leaf"]
    root_a, root_b = (r["params"]["root_gaussian"] for r in reports)
    assert int(perm[root_b]) == root_a                     # the same Gaussian, named in its file


def test_torch_numerics_run_single_threaded(monkeypatch):
    """fit_leaves and the texture-bake renderer run with 1 torch thread whatever the caller set,
    and give the caller's setting back."""
    import leaffit_usd.fit.adam as adam
    import leaffit_usd.fit.register as reg
    from samples.synthetic.fit import make_plant
    from leaffit_usd.splats import render

    seen = []
    real = adam.render_orthographic

    def spy(*a, **k):
        seen.append(torch.get_num_threads())
        return real(*a, **k)

    monkeypatch.setattr(adam, "render_orthographic", spy)
    plant = make_plant(n_leaves=3, n_gaussians=1500, seed=1)
    saved = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        reg.fit_leaves(plant.cloud, plant.seg, reg.FitParams(K=8, steps=2, refine=0))
        assert seen and set(seen) == {1}
        assert torch.get_num_threads() == 2
        seen.clear()
        monkeypatch.setattr(render, "render_orthographic", spy)
        rng = np.random.default_rng(0)
        m = rng.normal(size=(50, 3))
        cov = np.tile(np.eye(3) * 1e-3, (50, 1, 1))
        render.render_orthographic_np(m, cov, np.ones((50, 3)), np.full(50, 0.8), 16, 16, (-2, 2, -2, 2))
        assert seen == [1] and torch.get_num_threads() == 2
        with deterministic_torch():
            with deterministic_torch():                        # re-entrant
                assert torch.get_num_threads() == 1
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(saved)


def test_blas_runs_single_threaded_inside_and_is_restored():
    """numpy's BLAS runs on one thread inside the block (OpenBLAS' threads spin on a busy
    machine: the registration's tall-thin products were 10x slower), the caller's setting after."""
    from threadpoolctl import threadpool_info, threadpool_limits

    np.ones((4, 4)) @ np.ones((4, 4))                       # BLAS loaded
    with threadpool_limits(limits=2, user_api="blas"):
        before = [d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"]
        assert before and set(before) == {2}
        with deterministic_torch():
            with deterministic_torch():
                inner = [d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"]
            assert set(inner) == {1}
            assert {d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"} == {1}
        assert [d["num_threads"] for d in threadpool_info() if d["user_api"] == "blas"] == before


def test_threads_overlapping_in_the_block_keep_one_torch_thread_until_the_last_leaves():
    """The setting is process-wide: a thread that entered first and leaves first must not give
    the caller's thread count back while another thread is still inside (the texture bake
    renders its layers on two threads)."""
    import threading

    first_in, second_in, first_out = threading.Event(), threading.Event(), threading.Event()
    seen = []

    def first():
        with deterministic_torch():
            first_in.set()
            second_in.wait(5)
        first_out.set()

    def second():
        first_in.wait(5)
        with deterministic_torch():
            second_in.set()
            first_out.wait(5)
            seen.append(torch.get_num_threads())     # the first thread has left by now

    saved = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        ts = [threading.Thread(target=first), threading.Thread(target=second)]
        for t in ts:
            t.start()
        for t in ts:
            t.join(10)
        assert seen == [1]
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(saved)
