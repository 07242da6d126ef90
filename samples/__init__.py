"""Procedural 3DGS plants with ground truth (see samples/README.md and ``samples.generate``).

Public API (imported lazily so ``python -m samples.generate`` runs cleanly):
``PlantSpec``, ``make_plant``, ``save_plant``, ``load_ground_truth``, ``GroundTruth``,
``benchmark_suite``, ``committed_plants``, ``preset``, ``PRESETS``, ``PLANTS_DIR``.
"""
from pathlib import Path

PLANTS_DIR = Path(__file__).resolve().parent / "plants"

__all__ = ["PRESETS", "GroundTruth", "PlantSpec", "benchmark_suite", "committed_plants",
           "load_ground_truth", "make_plant", "preset", "save_plant", "PLANTS_DIR"]


def __getattr__(name):
    if name in __all__:
        from samples import generate

        return getattr(generate, name)
    raise AttributeError(name)
