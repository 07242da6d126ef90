"""Procedural 3DGS plants with ground truth (see samples/README.md and ``samples.generate``).

Public API (imported lazily so ``python -m samples.generate`` runs cleanly):
``PlantSpec``, ``make_plant``, ``save_plant``, ``load_ground_truth``, ``GroundTruth``,
``benchmark_suite``, ``committed_plants``, ``preset``, ``PRESETS``, ``PLANTS_DIR``,
``ensure_plants``.
"""
from pathlib import Path

PLANTS_DIR = Path(__file__).resolve().parent / "plants"

__all__ = ["PRESETS", "GroundTruth", "PlantSpec", "benchmark_suite", "capture_suite", "committed_plants",
           "load_ground_truth", "make_plant", "preset", "save_plant", "PLANTS_DIR", "ensure_plants"]


def ensure_plants(directory: Path = PLANTS_DIR) -> list[Path]:
    """The sample plants (``committed_plants()``) as ``NAME.ply`` + ``NAME.gt.npz`` in
    ``directory``, generating the missing ones (deterministic: same spec and seed, same bytes).
    They are not in git (``make`` generates them at set-up); returns the PLY paths."""
    from samples import generate

    out = []
    for name, (spec, seed) in generate.committed_plants().items():
        ply, gt = directory / f"{name}.ply", directory / f"{name}.gt.npz"
        if not (ply.is_file() and gt.is_file()):
            generate.save_plant(*generate.make_plant(spec, seed), directory, name)
        out.append(ply)
    return out


def __getattr__(name):
    if name in __all__:
        from samples import generate

        return getattr(generate, name)
    raise AttributeError(name)
