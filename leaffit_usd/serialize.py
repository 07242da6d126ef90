"""Save and load the pipeline's dataclass values as .npz (arrays) + JSON (scalars, dicts).

Each stage's result is a dataclass of numpy arrays and plain scalars; ``save_value`` writes its
fields to one .npz (non-array fields JSON-encoded under ``__json__``), atomically.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np

from leaffit_usd.io_util import atomic_path


def save_value(value, path) -> None:
    """Write a dataclass of arrays/scalars to ``path`` (.npz), atomically."""
    arrays, plain = {}, {}
    for f in dataclasses.fields(value):
        v = getattr(value, f.name)
        if isinstance(v, np.ndarray):
            arrays[f.name] = v
        else:
            plain[f.name] = v
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, __json__=np.array(json.dumps(plain)), **arrays)


def load_value(cls, path):
    """Read what :func:`save_value` wrote back into ``cls``."""
    with np.load(path, allow_pickle=False) as z:
        plain = json.loads(str(z["__json__"])) if "__json__" in z else {}
        arrays = {k: z[k] for k in z.files if k != "__json__"}
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in {**plain, **arrays}.items() if k in names})
