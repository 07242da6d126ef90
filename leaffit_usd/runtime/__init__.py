"""Runtime: turn a LeafFit stage into explicit leaves.

* :mod:`leaffit_usd.runtime.evaluator` — the CPU reference evaluator (numpy, vectorised over
  leaves, built on ``leaffit_usd.fit.mls``): ``evaluate(asset) -> BakedLeaves``.
* :mod:`leaffit_usd.runtime.bake` — writers for ``leaffit-usd bake`` (.npz, one-Mesh-per-leaf USD).
* :mod:`leaffit_usd.runtime.shader` — the GLSL deformer snippet (``runtime/glsl/``) and a headless
  moderngl runner used to prove GLSL == CPU.

Typical use::

    from leaffit_usd.usd.reader import read_stage
    from leaffit_usd.runtime import evaluate
    leaves = evaluate(read_stage("plant.usda"))          # input-capture frame
    leaves.vertices, leaves.faces, leaves.leaf_vertex_ids
"""
from leaffit_usd.runtime.evaluator import BakedLeaves, LeafEvaluator, evaluate, instance_matrices

__all__ = ["BakedLeaves", "LeafEvaluator", "evaluate", "instance_matrices"]
